"""NeRF / instant-ngp ``transforms.json``.

Camera-to-world matrices already use OpenGL camera axes and are kept as they are (NeRF
synthetic scenes and ``colmap2nerf.py`` output are Z-up; instant-ngp's internal axis swaps
are not applied). Intrinsics: ``fl_x fl_y cx cy`` (COLMAP's corner-based convention, as
ours) or ``camera_angle_x`` with the principal point at the image centre; any of them may
be given per frame. ``k1 k2 [k3] p1 p2`` are OpenCV distortion. Masks come from a
``masks/`` folder next to the images (matched by file stem) or else from RGBA alpha.
Extensions read here: per-frame ``lights`` and a top-level ``environment`` as in
``capture.json``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from ...errors import InputError, require
from ..format import check_pose, parse_environment, parse_lights
from ..images import image_size
from ..model import Camera, Capture, Frame
from .common import find_image

NAMES = ("transforms.json", "transforms_train.json")
DISTORTION = ("k1", "k2", "k3", "p1", "p2")


def find(path: Path) -> Path | None:
    """The transforms file that ``path`` names or holds."""
    if path.is_file():
        return path if path.suffix == ".json" and path.name != "capture.json" else None
    return next((path / n for n in NAMES if (path / n).is_file()), None)


def _image_path(root: Path, file_path: str) -> Path:
    path = root / file_path
    if path.suffix or path.is_file():
        return path
    return find_image(path.parent, path.name) or path.with_suffix(".png")  # NeRF synthetic omits it


def _has_alpha(path: Path) -> bool:
    if not path.is_file() or path.suffix.lower() not in (".png", ".tif", ".tiff"):
        return False
    try:
        with Image.open(path) as im:
            return "A" in im.mode
    except Exception:  # unreadable images are reported by validation, naming the file
        return False


def _camera(doc: dict, frame: dict, image: Path, path: Path, where: str) -> Camera:
    get = lambda key: frame.get(key, doc.get(key))  # noqa: E731  (per-frame values win)
    if get("w") is not None and get("h") is not None:
        w, h = int(get("w")), int(get("h"))
    else:
        w, h = image_size(image)
    if get("fl_x") is not None:
        fx = float(get("fl_x"))
    elif get("camera_angle_x") is not None:
        fx = 0.5 * w / math.tan(0.5 * float(get("camera_angle_x")))
    else:
        raise InputError(path, f"{where}: no focal length (fl_x or camera_angle_x)", "add fl_x or camera_angle_x")
    if get("fl_y") is not None:
        fy = float(get("fl_y"))
    elif get("camera_angle_y") is not None and get("fl_x") is None:
        fy = 0.5 * h / math.tan(0.5 * float(get("camera_angle_y")))
    else:
        fy = fx
    cx = float(get("cx")) if get("cx") is not None else 0.5 * w
    cy = float(get("cy")) if get("cy") is not None else 0.5 * h
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64)
    except KeyError as err:
        raise InputError(path, f"{where} has no transform_matrix", "give every frame a transform_matrix") from err
    except (TypeError, ValueError) as err:
        raise InputError(path, f"{where}: transform_matrix is not a 4x4 number matrix",
                         "write 4 rows of 4 numbers") from err
    if c2w.shape == (3, 4):
        c2w = np.vstack([c2w, [0, 0, 0, 1]])
    require(c2w.shape == (4, 4), path, f"{where}: transform_matrix has shape {c2w.shape}, not 4x4",
            "write 4 rows of 4 numbers")
    check_pose(c2w, path, where)
    distortion = {k: float(get(k)) for k in DISTORTION if get(k)}
    require(all(math.isfinite(v) for v in (fx, fy, cx, cy, *distortion.values())) and fx > 0 and fy > 0,
            path, f"{where}: intrinsics must be finite with focal length > 0", "fix the intrinsics")
    return Camera(w, h, fx, fy, cx, cy, c2w, distortion)


def load(path: Path, workdir: Path | None = None) -> Capture:
    path = find(path)
    root = path.parent
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise InputError(path, f"invalid JSON (line {err.lineno})", "fix or regenerate the file") from err
    items = doc.get("frames") or []
    require(isinstance(items, list) and len(items) > 0, path, "no frames", "list frames with file_path")
    frames, names = [], set()
    for i, item in enumerate(items):
        require("file_path" in item, path, f"frame {i} has no file_path", "give every frame a file_path")
        image = _image_path(root, item["file_path"])
        name = image.stem if image.stem not in names else f"{image.stem}_{i:04d}"
        names.add(name)
        where = f"frame {name}"
        frames.append(Frame(name=name, image=image, camera=_camera(doc, item, image, path, where),
                            lights=parse_lights(item.get("lights"), path, where)))
    _attach_masks(frames, root)
    return Capture(root=root, frames=frames, environment=parse_environment(doc.get("environment"), root, path),
                   provenance={"source": "nerf", "path": str(path)})


def _attach_masks(frames: list[Frame], root: Path) -> None:
    """Masks from ``masks/`` next to the images folder (all frames), else from RGBA alpha."""
    images = frames[0].image.parent
    folder = (root if images == root else images.parent) / "masks"
    if folder.is_dir():
        for frame in frames:
            frame.mask = find_image(folder, frame.image.stem)
            require(frame.mask is not None, folder / f"{frame.image.stem}.png", "mask missing for this frame",
                    "add a mask for every frame (same stem as the image) or remove the masks folder")
    elif all(_has_alpha(f.image) for f in frames):
        for frame in frames:
            frame.mask = frame.image
