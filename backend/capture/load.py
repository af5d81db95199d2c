"""The entry for reading any capture: our format (a folder with ``capture.json``) or any
importable layout (NeRF ``transforms.json``, a COLMAP model, IDR/NeuS ``cameras*.npz``,
Middlebury ``*_par.txt``, AliceVision), so users never convert by hand."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .format import FILENAME, load_native
from .importers import import_any
from .model import Capture
from .validate import validate_capture


def load_capture(path: str | Path, validate: bool = True) -> Capture:
    """Load a capture folder in our format or any importable layout."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "capture not found", "give a capture folder, transforms.json or COLMAP model")
    folder = path if path.is_dir() else path.parent
    if path.is_dir() and (path / FILENAME).is_file() or path.name == FILENAME:
        capture = load_native(folder)
    else:
        capture = import_any(path)
    if validate:
        validate_capture(capture)
    return capture
