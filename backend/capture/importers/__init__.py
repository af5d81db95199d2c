"""Importers: other capture layouts read into our capture model.

``import_any`` recognises the layout of a path and dispatches. Files an importer has to
derive (Middlebury masks, COLMAP's sparse points as PLY) are written into ``workdir`` when
one is given, else left out; nothing is ever written next to the source."""

from __future__ import annotations

from pathlib import Path

from ...errors import InputError
from ..model import Capture
from . import alicevision, colmap, idr, middlebury, nerf

# name, module, what the user gives
LAYOUTS = (
    ("NeRF / instant-ngp", nerf, "transforms.json (or its folder)"),
    ("COLMAP", colmap, "a sparse model folder with cameras/images .txt or .bin (or its project folder)"),
    ("IDR / NeuS", idr, "a folder with cameras*.npz, image/ and mask/"),
    ("Middlebury", middlebury, "*_par.txt (or its folder)"),
    ("AliceVision", alicevision, "a folder with P/*_P.txt and images/"),
)


def detect(path: str | Path) -> str | None:
    """The name of the layout ``path`` holds, or None."""
    path = Path(path)
    return next((name for name, module, _ in LAYOUTS if module.find(path) is not None), None)


def import_any(path: str | Path, workdir: str | Path | None = None, images: str | Path | None = None) -> Capture:
    """Read any supported layout into a :class:`Capture` (not yet validated).

    ``workdir`` receives derived files; ``images`` is the frames folder where the layout does
    not fix it (COLMAP)."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "capture not found", "give a capture folder or a file of a supported layout")
    for name, module, _ in LAYOUTS:
        if module.find(path) is not None:
            kwargs = {"images": images} if module is colmap else {}
            return module.load(path, workdir=workdir, **kwargs)
    accepted = "; ".join(f"{name}: {given}" for name, _, given in LAYOUTS)
    raise InputError(path, "not a capture layout we can read",
                     f"give capture.json's folder or one of: {accepted}")
