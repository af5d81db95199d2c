"""A phone's auto-exposure and white-balance drift over a video, for synthetic captures
(``synth --exposure-drift STOPS --white-balance-drift STOPS``).

Frame i of N records g_i x (the scene's radiance), with (in stops, channels R, G, B)

    log2 g_i = E sin(t_i + p) (1, 1, 1) + W sin(t_i + q) (1, 0, -1) + W sin(t_i + r) (-1/2, 1, -1/2),
    t_i = 2 pi i / N

E the auto-exposure's amplitude, W the white balance's: a colour-temperature swing (red
against blue) and a tint swing (green against both), the phases p, q, r drawn from the seed.
One slow swing over the video, smooth in the frame index as a phone's metering follows the
view. The white-balance terms sum to zero over the channels, so a frame's exposure (its mean
log2-gain) is E sin(t_i + p) alone. Over N evenly spaced frames each sine sums to zero, so the
mean log-gain of every channel is exactly 0: the gains are in the gauge of the fit
(backend.lighting.exposure.CONVENTION) and the true albedo is the one the fit should find."""

from __future__ import annotations

import numpy as np

CONVENTION = "mean log-gain over the frames = 0 per channel (geometric mean 1), as the fit's gauge"


def drift_gains(frames: int, exposure_stops: float, white_balance_stops: float, seed: int = 0) -> np.ndarray:
    """The (frames, 3) gains of the model above (all 1 for zero amplitudes)."""
    if frames < 1:
        return np.ones((0, 3))
    p, q, r = np.random.default_rng([seed, 7151]).uniform(0, 2 * np.pi, 3)
    t = 2 * np.pi * np.arange(frames)[:, None] / frames
    stops = (exposure_stops * np.sin(t + p) * np.array([1.0, 1.0, 1.0])
             + white_balance_stops * np.sin(t + q) * np.array([1.0, 0.0, -1.0])
             + white_balance_stops * np.sin(t + r) * np.array([-0.5, 1.0, -0.5]))
    return np.exp2(stops)


def truth(names: list[str], gains: np.ndarray, exposure_stops: float, white_balance_stops: float) -> dict:
    """The capture's ground-truth ``exposure`` document (gt/exposure.json)."""
    return {"model": "per-frame", "convention": CONVENTION, "exposure_stops": exposure_stops,
            "white_balance_stops": white_balance_stops,
            "gains": {n: [round(float(x), 6) for x in g] for n, g in zip(names, gains)}}
