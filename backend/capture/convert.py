"""Writing a capture into a folder in our format (the ``import`` and ``capture-from-video``
commands): frames copied as they are where possible; frames with lens distortion or
non-square pixels resampled to an ideal pinhole camera; ``max_size`` downscales (box filter,
in linear light). Masks are always written as 8-bit PNGs. :func:`import_capture` is the
``import`` command's whole job: any importable source to a new, validated capture folder."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from .. import fsio
from ..errors import require
from .format import FILENAME, save_capture
from .images import area_resize, read_mask, read_rgba, srgb_to_linear, write_image, write_mask
from .importers import import_any
from .load import load_capture
from .model import Capture, Environment, Frame
from .undistort import needs_resampling, pinhole, resample
from .validate import validate_capture

COPYABLE = {".png", ".jpg", ".jpeg", ".exr", ".hdr"}


def import_capture(source: Path, out: Path, max_size: int | None = None, frames: int | None = None,
                   images: str | None = None, overwrite: bool = False) -> Capture:
    """Write the capture at ``source`` (any importable layout) into the new folder ``out``:
    ``frames`` evenly spaced frames, downscaled to ``max_size``. ``out`` appears only once it
    is complete and reads back validated. Returns the capture as written."""
    require(max_size is None or max_size >= 8, None, f"--max-size {max_size} is too small", "give at least 8 pixels")
    require(frames is None or frames >= 1, None, f"--frames {frames} is below 1", "give 1 or more")
    with fsio.atomic_dir(Path(out), replace=overwrite) as tmp:
        work = tmp / ".import"
        capture = read_source(Path(source), work, images)
        validate_capture(capture)
        written = convert(select(capture, frames), tmp, max_size)
        shutil.rmtree(work, ignore_errors=True)
        save_capture(written)
        load_capture(tmp)  # what we wrote must read back and validate
    return written


def read_source(src: Path, workdir: Path, images: str | None) -> Capture:
    if (src.is_dir() and (src / FILENAME).is_file()) or src.name == FILENAME:
        return load_capture(src, validate=False)
    return import_any(src, workdir=workdir, images=images)


def select(capture: Capture, count: int | None) -> Capture:
    """``count`` frames spread evenly over the capture (all when None)."""
    if count is None or count >= len(capture.frames):
        return capture
    keep = np.unique(np.linspace(0, len(capture.frames) - 1, count).round().astype(int))
    capture.frames = [capture.frames[i] for i in keep]
    return capture


def convert(capture: Capture, folder: Path, max_size: int | None) -> Capture:
    """Write frames, masks, environment and points of ``capture`` into ``folder``."""
    converted = [_convert_frame(f, folder, max_size) for f in capture.frames]
    frames, resampled = [f for f, _ in converted], sum(warped for _, warped in converted)
    env = capture.environment
    if env is not None:
        path = folder / f"environment{env.path.suffix.lower()}"
        shutil.copyfile(env.path, path)
        env = Environment(path, env.strength, env.rotation_z_deg, env.provenance)
    points = None
    if capture.points is not None and Path(capture.points).is_file():
        points = folder / "points.ply"
        shutil.copyfile(capture.points, points)
    truth = {k: str((capture.root / v).resolve()) if isinstance(v, str) else v
             for k, v in capture.ground_truth.items()}
    provenance = dict(capture.provenance, **{"import": {"resampled_frames": resampled, "max_size": max_size}})
    return Capture(folder, frames, env, points, provenance, truth, capture.camera_response)


def _resize(image: np.ndarray, width: int, height: int, nearest: bool = False) -> np.ndarray:
    """Area averaging (``area_resize``); ``nearest``: the input pixel under each output
    pixel's centre (labels)."""
    if image.shape[:2] == (height, width):
        return image
    if not nearest:
        return area_resize(image, width, height)
    rows = np.minimum(((np.arange(height) + 0.5) * image.shape[0] / height).astype(int), image.shape[0] - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * image.shape[1] / width).astype(int), image.shape[1] - 1)
    return np.asarray(image, np.float32)[rows][:, cols]


def _convert_frame(frame: Frame, folder: Path, max_size: int | None) -> tuple[Frame, bool]:
    """The frame written into ``folder``, and whether it was resampled to a pinhole camera."""
    factor = min(1.0, max_size / max(frame.camera.width, frame.camera.height)) if max_size else 1.0
    scaled = frame.camera.scaled(factor) if factor < 1.0 else frame.camera
    warp = needs_resampling(scaled)  # rounded sizes can make pixels non-square too
    target = pinhole(scaled) if warp else scaled

    def transform(array: np.ndarray, labels: bool = False) -> np.ndarray:
        array = _resize(array, scaled.width, scaled.height, nearest=labels)
        return resample(array, scaled, order=0 if labels else 1) if warp else array

    suffix = frame.image.suffix.lower()
    if target is frame.camera and suffix in COPYABLE:
        image = folder / "images" / f"{frame.name}{suffix}"
        image.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(frame.image, image)
    else:
        pixels, linear = read_rgba(frame.image)
        if not linear:
            pixels[..., :3] = srgb_to_linear(pixels[..., :3])
        image = folder / "images" / f"{frame.name}{'.exr' if linear else '.png'}"
        write_image(image, transform(pixels))
    out = Frame(frame.name, image, target, lights=frame.lights)
    if frame.mask is not None:
        out.mask = folder / "masks" / f"{frame.name}.png"
        write_mask(out.mask, np.clip(transform(read_mask(frame.mask)), 0, 1))
    if frame.material_mask is not None:  # integer labels: nearest neighbour, stored as value / 255
        out.material_mask = folder / "materials" / f"{frame.name}.png"
        write_mask(out.material_mask, transform(read_rgba(frame.material_mask)[0][..., 0], labels=True))
    return out, warp
