"""The camera response from the frames' background.

Where a frame's background is visible (outside the mask, not clipped) it shows the same
surroundings the map recorded, so per channel the background's linear colour over the map's
colour in the same directions (at the estimated rotation; parallax ignored) is
exposure × white balance × strength, with no assumption about the object's albedo. The
match is trusted when the gains explain the background (small relative residual) and the albedo
it implies for the object (0.5 × object gain / background gain) is plausible; otherwise the
response stays normalised (exposure 1, white balance 1, mean albedo 0.5; see :mod:`.align`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..capture.model import CameraResponse
from ..geometry.raycast import pixel_rays
from .transport import ALBEDO

MIN_PIXELS = 200
MAX_ERROR = 0.25  # squared residual of the background fit relative to the background's energy
ALBEDO_RANGE = (0.02, 1.0)


@dataclass
class BackgroundMatch:
    """The frames' background fitted to the map's radiance in the same directions."""

    gains: np.ndarray  # frame ≈ gain × map radiance, per channel
    error: float  # squared residual relative to the background's energy (1 when it is black)
    pixels: int

    def provenance(self) -> dict:
        """The match as JSON, for capture.json's provenance."""
        return {"gains": [float(g) for g in self.gains], "error": round(self.error, 4), "pixels": self.pixels}


def lookup(env: np.ndarray, dirs: np.ndarray, rotation_z_deg: float) -> np.ndarray:
    """Map radiance in world directions (nearest texel), placed as docs/capture-format.md says."""
    a = np.radians(rotation_z_deg)
    x = np.cos(a) * dirs[:, 0] - np.sin(a) * dirs[:, 1]
    y = np.sin(a) * dirs[:, 0] + np.cos(a) * dirs[:, 1]
    u = (0.5 - np.arctan2(y, x) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(dirs[:, 2], -1, 1)) / np.pi
    h, w = env.shape[:2]
    return env[np.minimum((v * h).astype(int), h - 1), np.minimum((u * w).astype(int), w - 1)]


def match_background(samples, env: np.ndarray, rotation_z_deg: float) -> BackgroundMatch | None:
    """Least-squares per-channel gains of the frames' background onto the map, or None when
    there is too little background. ``samples``: (camera, linear frame, background pixels)."""
    frame, sky = [], []
    for camera, rgb, background in samples:
        ys, xs = np.nonzero(background)
        if not len(xs):
            continue
        _, dirs = pixel_rays(camera, np.c_[xs, ys])
        frame.append(rgb[ys, xs])
        sky.append(lookup(env, dirs, rotation_z_deg))
    if sum(len(f) for f in frame) < MIN_PIXELS:
        return None
    frame, sky = np.concatenate(frame).astype(np.float64), np.concatenate(sky).astype(np.float64)
    gains = (frame * sky).sum(0) / np.maximum((sky ** 2).sum(0), 1e-30)
    energy = float((frame ** 2).sum())
    error = float(((frame - gains * sky) ** 2).sum()) / energy if energy > 0 else 1.0
    return BackgroundMatch(gains, error, len(frame))


def camera_response(object_gains, background: BackgroundMatch | None) -> tuple[CameraResponse, float, str]:
    """(response, environment strength, how they were set) from the object's per-channel gains
    (render with albedo 0.5 and strength 1 onto the frames) and the background match."""
    object_gains = np.asarray(object_gains, np.float64)
    if background is not None and background.error <= MAX_ERROR and np.all(background.gains > 0):
        albedo = ALBEDO * object_gains / background.gains
        if np.all((albedo >= ALBEDO_RANGE[0]) & (albedo <= ALBEDO_RANGE[1])):
            strength = float(background.gains.mean())
            balance = tuple(float(g) for g in background.gains / strength)
            return CameraResponse(1.0, balance, "srgb", "estimated"), strength, "background"
    return CameraResponse(provenance="normalised"), float(object_gains.mean()), "mean albedo 0.5"
