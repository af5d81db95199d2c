"""The on-disk capture format (docs/capture-format.md): a folder with ``capture.json``.

Reading and writing our own format only; :func:`backend.capture.load.load_capture` is the
entry that reads any capture (ours or an importable layout)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .. import fsio
from ..errors import InputError, require
from .model import Camera, CameraResponse, Capture, Environment, Frame, PointLight

FORMAT = "shape-from-tracing-capture"
VERSION = 1
FILENAME = "capture.json"


def _matrix(value, path: Path, where: str) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputError(path, f"{where}: camera_to_world is not a 4x4 number matrix",
                         "write 4 rows of 4 numbers") from err
    if m.shape == (3, 4):
        m = np.vstack([m, [0, 0, 0, 1]])
    require(m.shape == (4, 4), path, f"{where}: camera_to_world has shape {m.shape}, not 4x4",
            "write 4 rows of 4 numbers")
    return m


def check_pose(m: np.ndarray, path, where: str) -> None:
    """A camera-to-world matrix must be finite with an invertible, orthogonal rotation."""
    require(bool(np.all(np.isfinite(m))), path, f"{where}: camera pose contains NaN or Inf",
            "re-solve the cameras or drop this frame")
    R = m[:3, :3]
    scale = np.cbrt(abs(np.linalg.det(R)))
    require(scale > 1e-8, path, f"{where}: camera pose is not invertible (singular rotation)",
            "re-solve the cameras or drop this frame")
    err = np.abs(R.T @ R / scale**2 - np.eye(3)).max()
    require(err < 1e-3, path, f"{where}: camera rotation is not orthogonal (error {err:.2g})",
            "write a rigid camera-to-world transform")


def parse_camera(d: dict, path: Path, where: str) -> Camera:
    try:
        cam = Camera(int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]),
                     float(d["cx"]), float(d["cy"]), _matrix(d["camera_to_world"], path, where),
                     {k: float(v) for k, v in d.get("distortion", {}).items()})
    except KeyError as err:
        raise InputError(path, f"{where}: camera lacks '{err.args[0]}'",
                         "give width, height, fx, fy, cx, cy and camera_to_world") from err
    vals = [cam.fx, cam.fy, cam.cx, cam.cy]
    require(all(math.isfinite(v) for v in vals) and cam.fx > 0 and cam.fy > 0, path,
            f"{where}: focal length and principal point must be finite, focal > 0",
            "fix the intrinsics")
    check_pose(cam.camera_to_world, path, where)
    return cam


def parse_lights(items, path: Path, where: str) -> list[PointLight]:
    lights = []
    for light in items or []:
        require(light.get("type", "point") == "point", path,
                f"{where}: light type '{light.get('type')}' is not supported", "use point lights")
        pos = np.asarray(light["position"], dtype=np.float64)
        inten = np.asarray(light.get("intensity_w_per_sr", light.get("intensity")), dtype=np.float64)
        if inten.ndim == 0:
            inten = np.full(3, float(inten))
        require(pos.shape == (3,) and inten.shape == (3,) and np.all(np.isfinite(pos))
                and np.all(np.isfinite(inten)) and np.all(inten >= 0), path,
                f"{where}: point light needs a finite position [x,y,z] and intensity [r,g,b] >= 0",
                "fix the light entry")
        lights.append(PointLight(pos, inten))
    return lights


def parse_environment(d: dict | None, root: Path, path: Path) -> Environment | None:
    if not d:
        return None
    env = Environment(root / d["path"], float(d.get("strength", 1.0)),
                      float(d.get("rotation_z_deg", 0.0)), str(d.get("provenance", "given")))
    require(math.isfinite(env.strength) and env.strength >= 0, path,
            "environment strength must be a finite number >= 0", "fix 'strength'")
    require(math.isfinite(env.rotation_z_deg), path, "environment rotation_z_deg is not finite",
            "give the rotation in degrees")
    return env


def parse_camera_response(d: dict | None, path: Path) -> CameraResponse:
    if not d:
        return CameraResponse()
    try:
        response = CameraResponse(float(d.get("exposure", 1.0)),
                                  tuple(float(x) for x in d.get("white_balance", (1.0, 1.0, 1.0))),
                                  str(d.get("curve", "srgb")), str(d.get("provenance", "given")))
    except (TypeError, ValueError) as err:
        raise InputError(path, "camera_response holds a value that is not a number",
                         "give exposure as a number and white_balance as 3 numbers") from err
    values = [response.exposure, *response.white_balance]
    require(len(response.white_balance) == 3 and all(math.isfinite(v) and v > 0 for v in values), path,
            "camera_response exposure and the 3 white_balance gains must be finite and > 0",
            "fix 'camera_response'")
    require(response.curve == "srgb", path, f"camera_response curve '{response.curve}' is not supported",
            "use 'srgb' (8-bit frames) and store linear frames as EXR")
    return response


def load_native(folder: Path) -> Capture:
    """The capture in ``folder``/capture.json (not yet validated)."""
    path = folder / FILENAME
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise InputError(path, f"invalid JSON (line {err.lineno})", "fix or regenerate the file") from err
    require(doc.get("format") == FORMAT, path, f"'format' is not '{FORMAT}'",
            "write a capture with python -m backend import")
    require(int(doc.get("version", 0)) <= VERSION, path,
            f"capture version {doc.get('version')} is newer than this backend reads", "update the backend")
    frames = []
    for i, fd in enumerate(doc.get("frames", [])):
        where = f"frame {fd.get('name', i)}"
        require("image" in fd, path, f"{where} has no 'image'", "give each frame an image path")
        frames.append(Frame(
            name=str(fd.get("name", f"{i:04d}")), image=folder / fd["image"],
            camera=parse_camera(fd.get("camera", {}), path, where),
            mask=folder / fd["mask"] if fd.get("mask") else None,
            material_mask=folder / fd["material_mask"] if fd.get("material_mask") else None,
            lights=parse_lights(fd.get("lights"), path, where)))
    require(len(frames) > 0, path, "capture has no frames", "add frames")
    return Capture(root=folder, frames=frames,
                   environment=parse_environment(doc.get("environment"), folder, path),
                   points=folder / doc["points"] if doc.get("points") else None,
                   provenance=doc.get("provenance", {}),
                   ground_truth=doc.get("ground_truth", {}),
                   camera_response=parse_camera_response(doc.get("camera_response"), path))


def capture_to_json(capture: Capture) -> dict:
    root = capture.root
    doc = {"format": FORMAT, "version": VERSION,
           "frames": [f.to_json(root) for f in capture.frames]}
    if capture.environment:
        doc["environment"] = capture.environment.to_json(root)
    if capture.camera_response != CameraResponse():
        doc["camera_response"] = capture.camera_response.to_json()
    if capture.points:
        doc["points"] = Path(capture.points).relative_to(root).as_posix()
    if capture.provenance:
        doc["provenance"] = capture.provenance
    if capture.ground_truth:
        doc["ground_truth"] = capture.ground_truth
    return doc


def save_capture(capture: Capture) -> Path:
    """Write ``capture.json`` into ``capture.root`` (atomically). Files it names must exist."""
    path = Path(capture.root) / FILENAME
    fsio.write_json(path, capture_to_json(capture))
    return path
