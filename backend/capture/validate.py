"""Checks a capture before any work starts, so bad input fails fast with one clear line."""

from __future__ import annotations

import numpy as np

from ..errors import InputError, require
from .format import check_pose
from .images import image_size, read_linear_rgb, read_mask, read_rgba
from .model import Capture


def validate_environment(capture: Capture) -> None:
    env = capture.environment
    if env is None:
        return
    arr, _ = read_rgba(env.path)
    h, w = arr.shape[:2]
    require(w == 2 * h, env.path, f"environment map is {w}x{h}, not equirectangular (2:1)",
            "use a latitude-longitude (equirectangular) HDR with width = 2 x height")
    require(bool(np.all(np.isfinite(arr[..., :3]))), env.path,
            "environment map contains NaN or Inf pixels", "re-export the HDR map")


SIGNAL = 1e-6  # linear: a frame whose brightest pixel in its mask is at most this holds no signal (black)


def _has_signal(image: np.ndarray, mask: np.ndarray | None) -> bool:
    """Whether any pixel inside ``mask`` (the whole frame without one) is brighter than ``SIGNAL``.
    A dim frame has signal (exposure is fitted); an empty mask has nothing to judge (the
    every-mask-empty check covers all of them empty), and a frame with non-finite pixels is
    left to the check that names them."""
    brightest = image.max(axis=-1) if image.ndim == 3 else image
    if mask is not None:
        inside = mask > 0.5
        if not inside.any():
            return True
        brightest = brightest[inside]
    if not np.all(np.isfinite(brightest)):
        return True
    return bool(brightest.max() > SIGNAL)


def validate_capture(capture: Capture, check_masks: bool = True) -> None:
    """Raise :class:`InputError` on the first problem found."""
    with_mask = [f for f in capture.frames if f.mask is not None]
    if with_mask and len(with_mask) < len(capture.frames):
        lacking = next(f for f in capture.frames if f.mask is None)
        raise InputError(lacking.image, f"frame {lacking.name} has no mask ({len(with_mask)} masks for "
                         f"{len(capture.frames)} frames)", "give one mask per frame (or none at all)")
    mask_area, dark = 0.0, []
    for frame in capture.frames:
        check_pose(frame.camera.camera_to_world, frame.image, f"frame {frame.name}")
        w, h = image_size(frame.image)
        require((w, h) == (frame.camera.width, frame.camera.height), frame.image,
                f"image is {w}x{h} but its camera says {frame.camera.width}x{frame.camera.height}",
                "fix the intrinsics or re-export the frame")
        for path in (frame.mask, frame.material_mask):
            if path is None:
                continue
            mw, mh = image_size(path)
            require((mw, mh) == (w, h), path, f"mask is {mw}x{mh} but its frame is {w}x{h}",
                    "resize the mask to the frame or re-export it")
        mask = read_mask(frame.mask) if check_masks and frame.mask is not None else None
        if mask is not None:
            mask_area += float(mask.mean())
        if not _has_signal(read_linear_rgb(frame.image), mask):
            dark.append(frame)
    if check_masks and with_mask:
        require(mask_area > 0, with_mask[0].mask.parent, "every mask is empty",
                "check the mask polarity (object = white) and the mask files")
    if dark:
        names = ", ".join(f.name for f in dark[:5]) + (f" and {len(dark) - 5} more" if len(dark) > 5 else "")
        where = "inside its mask" if len(dark) == 1 else "inside their masks"
        raise InputError(dark[0].image, f"{len(dark)} of {len(capture.frames)} frames have no signal {where} "
                         f"(black: {names})", "re-export those frames, or remove them and their masks from the capture")
    validate_environment(capture)
