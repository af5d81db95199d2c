"""Image I/O. 8-bit and 16-bit PNG/JPEG are sRGB and are linearised; EXR and HDR are linear.

All arrays are float32, rows top to bottom, RGB in the last axis."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from .. import fsio
from ..errors import InputError

LINEAR_SUFFIXES = {".exr", ".hdr"}


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def _read_linear(path: Path) -> np.ndarray:
    """An EXR or Radiance HDR file through Mitsuba's Bitmap: RGB(A), grey expanded to RGB."""
    import mitsuba as mi  # here: reading PNG/JPEG frames and masks needs no Mitsuba

    kind = "EXR" if path.suffix.lower() == ".exr" else "Radiance HDR"
    try:
        bitmap = mi.Bitmap(str(path))
    except Exception as err:
        raise InputError(path, f"cannot read {kind} ({err})".replace("\n", " "),
                         "re-export the file as OpenEXR or .hdr") from err
    fmt = bitmap.pixel_format()
    if fmt not in (mi.Bitmap.PixelFormat.RGB, mi.Bitmap.PixelFormat.RGBA, mi.Bitmap.PixelFormat.Y,
                   mi.Bitmap.PixelFormat.YA):
        raise InputError(path, f"{kind} has channels {[c.name for c in bitmap.struct_()]} but no R, G, B or Y",
                         "save the image with RGB channels")
    arr = np.array(bitmap.convert(component_format=mi.Struct.Type.Float32), dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    if fmt in (mi.Bitmap.PixelFormat.Y, mi.Bitmap.PixelFormat.YA):
        arr = np.concatenate([np.repeat(arr[..., :1], 3, -1), arr[..., 1:]], -1)
    return np.ascontiguousarray(arr)


def read_rgba(path: str | Path) -> tuple[np.ndarray, bool]:
    """Read an image as float32 HxWxC (C = 3 or 4) and whether it was linear on disk."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found", "check the path or re-export the frames")
    suffix = path.suffix.lower()
    if suffix in LINEAR_SUFFIXES:
        return _read_linear(path), True
    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I"):
                arr = np.asarray(im, dtype=np.float32) / 65535.0
                arr = arr[..., None]
            else:
                if mode not in ("RGB", "RGBA", "L", "LA"):
                    im = im.convert("RGBA" if "A" in mode or "transparency" in im.info else "RGB")
                arr = np.asarray(im, dtype=np.float32) / 255.0
    except Exception as err:
        raise InputError(path, f"cannot read image ({err.__class__.__name__})",
                         "replace the file with a valid PNG, JPEG or EXR") from err
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.shape[-1] in (1, 2):  # grey or grey+alpha
        grey = np.repeat(arr[..., :1], 3, -1)
        arr = np.concatenate([grey, arr[..., 1:]], -1)
    return arr.astype(np.float32), False


def read_linear_rgb(path: str | Path) -> np.ndarray:
    """Read an image as linear float32 RGB (sRGB files are decoded)."""
    arr, linear = read_rgba(path)
    rgb = arr[..., :3]
    return rgb if linear else srgb_to_linear(rgb)


def read_mask(path: str | Path) -> np.ndarray:
    """Read a mask as float32 HxW in [0, 1]: the alpha channel if present, else the mean of RGB."""
    arr, _ = read_rgba(path)
    m = arr[..., 3] if arr.shape[-1] == 4 else arr[..., :3].mean(-1)
    return np.clip(m, 0.0, 1.0).astype(np.float32)


def area_resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """``image`` (H, W) or (H, W, C) resampled to ``width`` x ``height`` by exact area
    averaging: output pixel (j, k) is the mean of the input over the rectangle it covers,
    [j W / width, (j + 1) W / width) x [k H / height, (k + 1) H / height), pixels read as
    constant over their unit squares (float32).

    This keeps the pixel-edge convention of ``Camera.scaled`` (c' = c s) at every factor.
    A filter that weighs whole input pixels by their centres (PIL's box filter) shifts the
    image by up to a quarter of an input pixel at a non-integer factor (1.5, 2.5) and widens
    every other output pixel, which the fit would read as a camera or surface error."""
    a = np.asarray(image, np.float32)
    if a.shape[:2] == (height, width):
        return a
    return _area_axis(_area_axis(a, height, 0), width, 1)


def _area_axis(a: np.ndarray, n: int, axis: int) -> np.ndarray:
    """``a`` averaged to ``n`` samples along ``axis`` (``area_resize``): differences of the
    running integral F(x) = sum_{i < floor x} a_i + frac(x) a_floor(x) at the n + 1 edges."""
    a = np.moveaxis(a, axis, 0)
    m = a.shape[0]
    if m == n:
        return np.moveaxis(a, 0, axis)
    total = np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, 0, dtype=np.float64)])
    edges = np.linspace(0.0, m, n + 1)
    i = np.minimum(edges.astype(int), m - 1)
    frac = (edges - i).reshape((-1,) + (1,) * (a.ndim - 1))
    integral = total[i] + frac * a[i]
    return np.moveaxis(((integral[1:] - integral[:-1]) * (n / m)).astype(np.float32), 0, axis)


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of an image without decoding its pixels where possible."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found", "check the path or re-export the frames")
    if path.suffix.lower() in LINEAR_SUFFIXES:
        arr, _ = read_rgba(path)
        return arr.shape[1], arr.shape[0]
    try:
        with Image.open(path) as im:
            return im.size
    except Exception as err:
        raise InputError(path, f"cannot read image ({err.__class__.__name__})",
                         "replace the file with a valid PNG, JPEG or EXR") from err


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write linear float data: EXR as is, PNG/JPEG sRGB-encoded (8-bit). Atomic."""
    path = Path(path)
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        image = image[..., None]
    suffix = path.suffix.lower()
    with fsio.atomic_path(path) as tmp:
        if suffix == ".exr":
            if image.shape[-1] == 1:
                image = np.repeat(image, 3, -1)
            name = "RGBA" if image.shape[-1] == 4 else "RGB"
            header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
            with OpenEXR.File(header, {name: np.ascontiguousarray(image)}) as f:
                f.write(str(tmp))
        else:
            enc = linear_to_srgb(image[..., :3])
            if image.shape[-1] == 4:
                enc = np.concatenate([enc, np.clip(image[..., 3:], 0, 1)], -1)
            data = np.round(enc * 255).astype(np.uint8)
            if data.shape[-1] == 1:
                data = data[..., 0]
            Image.fromarray(data).save(tmp, format="PNG" if suffix == ".png" else "JPEG")


def write_mask(path: str | Path, mask: np.ndarray) -> None:
    """Write a [0, 1] mask as an 8-bit greyscale PNG (no sRGB curve). Atomic."""
    data = np.round(np.clip(mask, 0, 1) * 255).astype(np.uint8)
    with fsio.atomic_path(path) as tmp:
        Image.fromarray(data).save(tmp, format="PNG")
