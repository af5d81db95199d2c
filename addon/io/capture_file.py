"""``capture.json`` as the add-on needs it: frames, cameras and lighting (bpy-free).

Cameras are ``camera_to_world`` 4x4 matrices with Blender camera axes and pinhole
intrinsics in pixels, the top-left pixel's centre at (0.5, 0.5) (docs/capture-format.md).
:func:`blender_camera` turns them into Blender's lens, sensor and shift exactly."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import AddonInputError, require

FORMAT = "shape-from-tracing-capture"
FILENAME = "capture.json"
SENSOR_WIDTH_MM = 36.0


@dataclass
class BlenderCamera:
    """A pinhole camera in Blender's terms (``sensor_fit`` is always ``HORIZONTAL``)."""

    matrix_world: np.ndarray  # 4x4 camera-to-world, Blender camera axes
    width: int
    height: int
    lens: float  # mm
    sensor_width: float  # mm
    shift_x: float
    shift_y: float
    pixel_aspect: float  # fy / fx; 1 for square pixels


@dataclass
class FrameInfo:
    name: str
    image: Path
    camera: BlenderCamera
    mask: Path | None = None
    lights: list[dict] = field(default_factory=list)


@dataclass
class CaptureInfo:
    root: Path
    frames: list[FrameInfo]
    environment: dict | None = None  # {"path": Path, "strength": float, "rotation_z_deg": float}


def blender_camera(cam: dict, path: Path | None = None, where: str = "camera") -> BlenderCamera:
    """Lens, sensor and shift for a capture camera. With a horizontal sensor fit the sensor
    width spans the image width and shifts are in units of it; pixels are fy/fx wide (the
    render's pixel aspect), which scales vertical distances by fx/fy."""
    try:
        w, h = int(cam["width"]), int(cam["height"])
        fx, fy, cx, cy = (float(cam[k]) for k in ("fx", "fy", "cx", "cy"))
        m = np.asarray(cam["camera_to_world"], dtype=np.float64)
    except KeyError as err:
        raise AddonInputError(path, f"{where}: camera lacks '{err.args[0]}'",
                              "give width, height, fx, fy, cx, cy and camera_to_world") from err
    except (TypeError, ValueError) as err:
        raise AddonInputError(path, f"{where}: camera values are not numbers",
                              "write numbers and a 4x4 matrix") from err
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    require(m.shape == (4, 4), path, f"{where}: camera_to_world has shape {m.shape}, not 4x4",
            "write 4 rows of 4 numbers")
    require(w > 0 and h > 0 and fx > 0 and fy > 0 and all(map(math.isfinite, (fx, fy, cx, cy))),
            path, f"{where}: image size and focal length must be positive and finite", "fix the intrinsics")
    require(bool(np.all(np.isfinite(m))), path, f"{where}: camera pose contains NaN or Inf",
            "re-solve the cameras or drop this frame")
    rot = m[:3, :3]
    scale = abs(np.linalg.det(rot)) ** (1 / 3)
    require(scale > 1e-8 and np.abs(rot.T @ rot / scale**2 - np.eye(3)).max() < 1e-3, path,
            f"{where}: camera rotation is not orthogonal", "write a rigid camera-to-world transform")
    return BlenderCamera(m, w, h, lens=fx / w * SENSOR_WIDTH_MM, sensor_width=SENSOR_WIDTH_MM,
                         shift_x=(0.5 * w - cx) / w, shift_y=(cy - 0.5 * h) / w * fx / fy,
                         pixel_aspect=fy / fx)


def _document(path: Path, fmt: str, fix_json: str, fix_format: str) -> dict:
    """The JSON object in ``path`` whose ``format`` is ``fmt``; AddonInputError (with the fix)
    when it is not JSON or not that format."""
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise AddonInputError(path, "invalid JSON", fix_json) from err
    require(isinstance(doc, dict) and doc.get("format") == fmt, path, f"'format' is not '{fmt}'", fix_format)
    return doc


def read_capture(path: str | Path) -> CaptureInfo:
    """Read a capture folder (or its ``capture.json``) without touching the images."""
    path = Path(path)
    if path.is_dir():
        path = path / FILENAME
    require(path.is_file(), path, "capture not found", "give a capture folder with capture.json "
            "(convert other layouts with 'python -m backend import')")
    doc = _document(path, FORMAT, "fix or regenerate the file", "write the capture with 'python -m backend import'")
    root = path.parent
    frames = []
    for i, fd in enumerate(doc.get("frames") or []):
        where = f"frame {fd.get('name', i)}"
        require("image" in fd and "camera" in fd, path, f"{where} lacks 'image' or 'camera'",
                "give each frame an image and a camera")
        frames.append(FrameInfo(str(fd.get("name", f"{i:04d}")), root / fd["image"],
                                blender_camera(fd["camera"], path, where),
                                root / fd["mask"] if fd.get("mask") else None,
                                list(fd.get("lights") or [])))
    require(bool(frames), path, "capture has no frames", "add frames")
    env = doc.get("environment")
    if env:
        env = {"path": root / env["path"], "strength": float(env.get("strength", 1.0)),
               "rotation_z_deg": float(env.get("rotation_z_deg", 0.0))}
    return CaptureInfo(root, frames, env)


REFINED_FORMAT = "shape-from-tracing-cameras"
REFINED_FILENAME = "cameras.json"


def with_refined_cameras(info: CaptureInfo, run: str | Path | None) -> CaptureInfo:
    """``info`` with the cameras a run refined (``RUN/cameras.json``, written by ``reconstruct
    --refine-cameras``) in place of the capture's, matched by frame name; ``info`` itself when
    the run wrote none. A frame the file does not name keeps its camera (a held-out view)."""
    path = Path(run) / REFINED_FILENAME if run is not None else None
    if path is None or not path.is_file():
        return info
    fix = "delete it to preview with the capture's cameras"
    doc = _document(path, REFINED_FORMAT, fix, fix)
    refined = {str(fd.get("name")): blender_camera(fd.get("camera") or {}, path, f"frame {fd.get('name')}")
               for fd in doc.get("frames") or [] if isinstance(fd, dict)}
    frames = [FrameInfo(f.name, f.image, refined.get(f.name, f.camera), f.mask, f.lights) for f in info.frames]
    return CaptureInfo(info.root, frames, info.environment)
