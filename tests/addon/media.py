"""Test media made on the fly: small videos (PyAV), EXR and PNG images, Cycles renders."""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np


def pattern(i: int, h: int = 48, w: int = 64) -> np.ndarray:
    """A sharp frame: checkerboard plus a square that moves with ``i`` (uint8 RGB)."""
    y, x = np.mgrid[:h, :w]
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = np.where(((x // 4) + (y // 4)) % 2 == 0, 220, 30)
    img[..., 1] = 90
    img[10:26, 4 + 3 * i:20 + 3 * i, 2] = 255
    return img


def box_blur(img: np.ndarray, radius: int = 4) -> np.ndarray:
    out = img.astype(np.float32)
    k = np.ones(2 * radius + 1) / (2 * radius + 1)
    for axis in (0, 1):
        out = np.apply_along_axis(lambda r: np.convolve(np.pad(r, radius, mode="edge"), k, "valid"), axis, out)
    return out.astype(np.uint8)


def write_video(path: Path, frames: list[np.ndarray], fps: int = 10, rotate_cw: int = 0) -> Path:
    """An H.264 MP4 of ``frames``; ``rotate_cw`` (0, 90, 180, 270) tags it as a phone tags
    portrait video: the track header's display matrix turns the stored frames clockwise."""
    import av

    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv444p"
        stream.options = {"crf": "0"}
        for img in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    if rotate_cw:
        set_display_rotation(path, rotate_cw)
    return path


def set_display_rotation(path: Path, rotate_cw: int) -> None:
    """Write the video track's display matrix (ISO 14496-12 ``tkhd``): a clockwise turn."""
    import struct

    data = bytearray(path.read_bytes())
    box = data.find(b"tkhd")
    assert box > 0, path
    version = data[box + 4]
    matrix = box + 8 + (32 if version == 1 else 20) + 16  # after times, track id, duration, layer...
    one = 1 << 16
    a, b, c, d = {90: (0, one, -one, 0), 180: (-one, 0, 0, -one), 270: (0, -one, one, 0)}[rotate_cw]
    struct.pack_into(">9i", data, matrix, a, b, 0, c, d, 0, 0, 0, 1 << 30)
    path.write_bytes(bytes(data))


def write_image(path: Path, pixels: np.ndarray, float_exr: bool = False) -> Path:
    """Save (rows, cols, 3|4) pixels, row 0 at the top: a linear EXR (the backend's writer)
    or a PNG storing round(255 * value) as is."""
    if float_exr:
        from backend.capture.images import write_image as write_linear

        write_linear(path, pixels)
    else:
        from PIL import Image

        Image.fromarray(np.rint(np.clip(pixels, 0, 1) * 255).astype(np.uint8)).save(path)
    return path


def spot_env(path: Path, u: float, v: float, width: int = 256, radius_px: float = 3.0) -> Path:
    """A black 2:1 EXR with one bright disc centred at texture coordinates (u, v)."""
    h = width // 2
    y, x = np.mgrid[:h, :width] + 0.5
    d = np.hypot(np.minimum(np.abs(x - u * width), width - np.abs(x - u * width)), y - v * h)
    img = np.zeros((h, width, 3), np.float32)
    img[d < radius_px] = 50.0
    return write_image(path, img, float_exr=True)


def render(scene, path: Path, samples: int = 16, transparent: bool = False) -> np.ndarray:
    """Render ``scene`` with Cycles (CPU) to a linear EXR; (rows, cols, 4), row 0 at the top."""
    from addon.images import read_rgba

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.render.film_transparent = transparent
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True, scene=scene.name)
    return read_rgba(path)[0]


def centroid(weights: np.ndarray) -> tuple[float, float]:
    """Weighted centre (x, y) in pixel coordinates, the top-left corner at (0, 0)."""
    rows, cols = np.mgrid[:weights.shape[0], :weights.shape[1]] + 0.5
    total = weights.sum()
    return float((weights * cols).sum() / total), float((weights * rows).sum() / total)
