"""Tiny synthetic videos and image folders for the video tests (PyAV, H.264)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage


def write_video(path: Path, frames: list[np.ndarray], fps: int = 24) -> Path:
    """Encode HxWx3 uint8 frames (even sizes) as near-lossless H.264 MP4."""
    import av

    h, w = frames[0].shape[:2]
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv444p"
        stream.options = {"crf": "4", "preset": "ultrafast"}
        for rgb in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def texture(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A periodic random texture with detail at several scales (uint8 RGB)."""
    rng = np.random.default_rng(seed)
    noise = sum(ndimage.zoom(rng.random((height // s, width // s)), s, order=1, mode="grid-wrap", grid_mode=True)
                for s in (1, 2, 4))
    grey = (noise - noise.min()) / np.ptp(noise)
    return np.round(np.stack([grey, grey[::-1], grey[:, ::-1]], -1) * 255).astype(np.uint8)


def moving_frames(n: int, width: int, height: int, blurred=(), step: int = 2) -> list[np.ndarray]:
    """Frame i shows the texture shifted i*step px to the right; listed frames are box-blurred."""
    base = texture(width, height)
    frames = []
    for i in range(n):
        rgb = np.roll(base, i * step, axis=1)
        if i in set(blurred):
            rgb = ndimage.uniform_filter(rgb.astype(np.float32), size=(7, 7, 1), mode="wrap").round().astype(np.uint8)
        frames.append(rgb)
    return frames


def match_index(rgb: np.ndarray, width: int, height: int, n: int, step: int = 2) -> int:
    """Which unblurred frame of ``moving_frames`` a decoded frame is closest to."""
    base = texture(width, height).astype(np.float32)
    errors = [np.abs(np.roll(base, i * step, axis=1) - rgb).mean() for i in range(n)]
    return int(np.argmin(errors))
