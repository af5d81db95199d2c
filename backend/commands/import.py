"""``import SRC --out CAPTURE``: write any importable capture in our format.

Frames are copied as they are where possible; frames with lens distortion or non-square
pixels are resampled to an ideal pinhole camera, and ``--max-size`` downscales (box filter,
in linear light). The output folder appears only once it is complete and validated."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from .. import fsio
from ..capture import load_capture
from ..capture.format import FILENAME, save_capture
from ..capture.images import read_mask, read_rgba, srgb_to_linear, write_image, write_mask
from ..capture.importers import import_any
from ..capture.model import Capture, Environment, Frame
from ..capture.undistort import needs_resampling, pinhole, resample
from ..capture.validate import validate_capture
from ..errors import require
from ..events import Emitter

COPYABLE = {".png", ".jpg", ".jpeg", ".exr", ".hdr"}


def add_arguments(parser):
    parser.add_argument("source", metavar="SRC",
                        help="capture folder, transforms.json, COLMAP model, IDR npz folder, Middlebury *_par.txt "
                             "or AliceVision folder")
    parser.add_argument("--out", required=True, metavar="CAPTURE", help="new capture folder to write")
    parser.add_argument("--max-size", type=int, metavar="PX", help="downscale frames so the longer side is at most PX")
    parser.add_argument("--frames", type=int, metavar="N", help="keep N frames, evenly spaced")
    parser.add_argument("--images", metavar="DIR", help="frames folder of a COLMAP model (default: images/ beside it)")
    parser.add_argument("--overwrite", action="store_true", help="replace CAPTURE if it exists")


def run(args) -> int:
    require(args.max_size is None or args.max_size >= 8, None, f"--max-size {args.max_size} is too small",
            "give at least 8 pixels")
    require(args.frames is None or args.frames >= 1, None, f"--frames {args.frames} is below 1", "give 1 or more")
    out = Path(args.out)
    with fsio.atomic_dir(out, replace=args.overwrite) as tmp:
        work = tmp / ".import"
        capture = read_source(Path(args.source), work, args.images)
        validate_capture(capture)
        written = convert(select(capture, args.frames), tmp, args.max_size)
        shutil.rmtree(work, ignore_errors=True)
        save_capture(written)
        load_capture(tmp)  # what we wrote must read back and validate
    Emitter()("done", result=str(out / FILENAME), frames=len(written.frames),
              resampled=written.provenance["import"]["resampled_frames"])
    return 0


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
        env = Environment(path, env.strength, env.rotation_z_deg)
    points = None
    if capture.points is not None and Path(capture.points).is_file():
        points = folder / "points.ply"
        shutil.copyfile(capture.points, points)
    truth = {k: str((capture.root / v).resolve()) if isinstance(v, str) else v
             for k, v in capture.ground_truth.items()}
    provenance = dict(capture.provenance, **{"import": {"resampled_frames": resampled, "max_size": max_size}})
    return Capture(folder, frames, env, points, provenance, truth)


def _resize(image: np.ndarray, width: int, height: int, nearest: bool = False) -> np.ndarray:
    from PIL import Image

    if image.shape[:2] == (height, width):
        return image
    channels = image[..., None] if image.ndim == 2 else image
    filt = Image.NEAREST if nearest else Image.BOX
    out = np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(channels[..., c], np.float32))
                               .resize((width, height), filt)) for c in range(channels.shape[-1])], -1)
    return out[..., 0] if image.ndim == 2 else out


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
