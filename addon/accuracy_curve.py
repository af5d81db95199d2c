"""The held-out accuracy curve in the sidebar (Track Accuracy; docs/protocol.md).

The backend redraws ``RUN/accuracy_time.png`` (held-out PSNR against run time, levels and
stages marked) after every score and then emits an ``accuracy`` event; :func:`show` copies
that PNG into one preview image, updated in place, which the Reconstruct panel draws with
``template_icon``. No datablock is left in the user's file."""

from __future__ import annotations

from pathlib import Path

import bpy
import bpy.utils.previews
import numpy as np

from .io.errors import AddonInputError
from .images import read_rgba

FIGURE = "accuracy_time.png"
KEY = "accuracy_time"

_previews = None  # the add-on's preview collection, while registered
_shown: dict = {"path": None, "loaded": False}


def _preview():
    if _previews is None:
        return None
    return _previews[KEY] if KEY in _previews else _previews.new(KEY)


def show(run_dir) -> bool:
    """Copy ``run_dir``/accuracy_time.png into the preview; False when it cannot be read yet."""
    preview = _preview()
    if preview is None or run_dir is None:
        return False
    path = Path(run_dir) / FIGURE
    try:
        rgba, _ = read_rgba(path)  # rows from the top; previews store them from the bottom
    except AddonInputError:
        return False
    h, w = rgba.shape[:2]
    preview.image_size = (w, h)
    preview.image_pixels_float.foreach_set(np.ascontiguousarray(rgba[::-1], np.float32).ravel())
    _shown.update(path=str(path), loaded=True)
    return True


def clear() -> None:
    """A new run: no curve until its first score."""
    _shown.update(path=None, loaded=False)


def shown() -> bool:
    return bool(_shown["loaded"])


def pixels() -> np.ndarray | None:
    """The preview's pixels (rows from the bottom, RGBA in [0, 1]), or None before a curve."""
    preview = _preview()
    if preview is None or not shown():
        return None
    w, h = preview.image_size
    out = np.empty(w * h * 4, np.float32)
    preview.image_pixels_float.foreach_get(out)
    return out.reshape(h, w, 4)


def icon_id() -> int:
    preview = _preview()
    return preview.icon_id if preview is not None and shown() else 0


def register() -> None:
    global _previews
    _previews = bpy.utils.previews.new()


def unregister() -> None:
    global _previews
    if _previews is not None:
        bpy.utils.previews.remove(_previews)
    _previews = None
    clear()
