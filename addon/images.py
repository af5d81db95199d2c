"""Reading image files into numpy through Blender's image loader (any format it reads)."""

from pathlib import Path

import bpy
import numpy as np

from .io.errors import AddonInputError


def read_rgba(path: str | Path) -> tuple[np.ndarray, bool]:
    """(rows, columns, 4) float32 pixels, row 0 at the top, and whether the file is linear
    (float formats); 8-bit files give their stored (display-encoded) values / 255."""
    path = Path(path)
    if not path.is_file():
        raise AddonInputError(path, "image not found", "check the path")
    try:
        image = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError as err:
        raise AddonInputError(path, "cannot read the image", "export it as PNG, JPEG or EXR") from err
    try:
        w, h = image.size
        if w * h == 0:
            raise AddonInputError(path, "cannot read the image", "export it as PNG, JPEG or EXR")
        channels = image.channels
        pixels = np.empty(w * h * channels, np.float32)
        image.pixels.foreach_get(pixels)
        pixels = pixels.reshape(h, w, channels)[::-1]
        linear = image.is_float
    finally:
        bpy.data.images.remove(image)
    if channels == 4:
        return np.ascontiguousarray(pixels), linear
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = pixels[..., :1] if channels == 1 else pixels[..., :3]
    return rgba, linear


def luminance(rgba: np.ndarray) -> np.ndarray:
    return rgba[..., :3] @ np.array([0.2126, 0.7152, 0.0722], np.float32)


def to_display(rgb: np.ndarray, linear: bool) -> np.ndarray:
    """sRGB-encoded values in [0, 1] (the encoding applied to linear pixels)."""
    rgb = np.clip(rgb, 0.0, 1.0)
    if not linear:
        return rgb
    return np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
