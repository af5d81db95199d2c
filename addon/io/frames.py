"""Frames of a capture folder: which video frames to keep, blur rejection and mask matching
(bpy-free, numpy only).

Import Video writes ``images/NNNN.png`` and ``frames.json`` (which video frame each image
came from) into the capture folder; Import Masks uses it to match masks to frames."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from .errors import AddonInputError, require
from .files import write_atomic

MANIFEST = "frames.json"
IMAGES, MASKS, MATERIALS = "images", "masks", "materials"
IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff", ".bmp", ".webp"}


def pick_frames(total: int, every_nth: int = 1, target_count: int = 0) -> list[int]:
    """0-based video frames to extract: ``target_count`` spread evenly when > 0, else every Nth."""
    if target_count > 0:
        if target_count >= total:
            return list(range(total))
        return sorted({int(round(x)) for x in np.linspace(0, total - 1, target_count)})
    return list(range(0, total, max(1, every_nth)))


def sharpness(gray: np.ndarray) -> float:
    """Variance of the 4-neighbour Laplacian: low for blurred frames."""
    g = np.asarray(gray, dtype=np.float64)
    if min(g.shape) < 3:
        return 0.0
    lap = g[1:-1, :-2] + g[1:-1, 2:] + g[:-2, 1:-1] + g[2:, 1:-1] - 4 * g[1:-1, 1:-1]
    return float(lap.var())


def sharp_enough(scores: list[float], threshold: float) -> list[bool]:
    """Keep frames at least ``threshold`` times as sharp as the median frame (0 keeps all)."""
    if threshold <= 0 or not scores:
        return [True] * len(scores)
    median = float(np.median(scores))
    return [s >= threshold * median for s in scores]


def match_masks(n_masks: int, source_frames: list[int], video_frames: int, where) -> list[int]:
    """For each frame, the index of its mask in a sequence of ``n_masks``: one mask per
    kept frame, or one per video frame (picked by the frame's source)."""
    if n_masks == len(source_frames):
        return list(range(n_masks))
    if video_frames and n_masks == video_frames:
        return list(source_frames)
    raise AddonInputError(where, f"{n_masks} masks match neither the {len(source_frames)} frames "
                                 f"nor the {video_frames} video frames",
                          "give one mask per imported frame or one per video frame")


def image_sequence(path: str | Path) -> list[Path]:
    """The images of a folder (or of the folder holding ``path``), in natural order."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    require(folder.is_dir(), path, "folder not found", "choose an image sequence folder")
    files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]
    require(bool(files), folder, "no images in the folder", "choose a folder of PNG/JPEG/EXR images")
    return sorted(files, key=lambda p: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)])


def mask_from_rgba(rgba: np.ndarray) -> np.ndarray:
    """Object = white (or opaque, when the alpha channel carries the mask): uint8 0/255."""
    rgba = np.asarray(rgba, dtype=np.float32)
    alpha = rgba[..., 3] if rgba.shape[-1] == 4 else None
    value = alpha if alpha is not None and alpha.min() < 0.99 else rgba[..., :3].max(-1)
    return np.where(value > 0.5, 255, 0).astype(np.uint8)


def frame_name(i: int) -> str:
    return f"{i:04d}"


def read_manifest(capture: str | Path) -> dict:
    """``frames.json`` of a capture folder (raises when frames were not imported)."""
    path = Path(capture) / MANIFEST
    require(path.is_file(), path, "no imported frames", "run Import Video first")
    try:
        doc = json.loads(path.read_text())
    except (ValueError, OSError) as err:
        raise AddonInputError(path, "unreadable frame list", "import the video again") from err
    require(isinstance(doc.get("frames"), list) and bool(doc["frames"]), path,
            "frame list is empty", "import the video again")
    return doc


def write_manifest(capture: str | Path, doc: dict) -> None:
    write_atomic(Path(capture) / MANIFEST, (json.dumps(doc, indent=2) + "\n").encode())
