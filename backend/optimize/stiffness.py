"""How stiff the Large Steps system is, chosen from the frames' colour variation (the rule:
``choose``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_erosion

SOFT = (2.0, 95.0)  # (lambda, gradient cap percentile)
STIFF = (20.0, 99.5)
TEXTURED = 0.05  # chromaticity spread above which a constant material cannot explain the frames


@dataclass
class Stiffness:
    lambda_: float
    clip: float
    chroma_spread: float | None  # None when not measured (both values given)
    reason: str

    def event(self) -> dict:
        return {"lambda": self.lambda_, "clip": self.clip,
                "chroma_spread": None if self.chroma_spread is None else round(self.chroma_spread, 4),
                "reason": self.reason}


def chroma_spread(views) -> float:
    """Median over views of the 90th-percentile chromaticity distance from the view's median."""
    spreads = []
    for v in views:
        brightness = v.target.sum(-1)
        inside = v.mask > 0.99 if v.mask is not None else brightness > 0
        inside = binary_erosion(inside, iterations=2)
        if inside.sum() < 20:
            continue
        lo, hi = np.percentile(brightness[inside], [10, 98])
        keep = inside & (brightness > max(lo, 1e-6)) & (brightness < hi)
        if keep.sum() < 20:
            continue
        chroma = v.target[keep] / brightness[keep, None]
        spreads.append(np.percentile(np.linalg.norm(chroma - np.median(chroma, 0), axis=1), 90))
    return float(np.median(spreads)) if spreads else 0.0


def choose(config, views, spatially_varying: bool) -> Stiffness:
    """The system for this run: the configured values win; otherwise soft unless one
    constant material must absorb a textured appearance.

    A soft system (lambda 2, gradients capped at the 95th percentile) lets detail converge
    fast, and wins when the material model can explain the frames' colours: a uniformly
    coloured object, or mesh colors that learn the texture. When one constant material must
    stand for a textured object, the texture left in the residual pushes a soft surface into
    bumps, and a stiff system (lambda 20, cap 99.5) is better (figures: docs/results.md).

    Texture is detected from chromaticity, which shading under white light does not change:
    the 90th percentile of the distance of object pixels' chromaticity (r, g, b) / (r + g + b)
    from its median, in the masks' interior, without the darkest and brightest pixels
    (shadows, highlights). A uniform object scores about 0. A coloured environment map (a sunset) also raises it; the stiff system is then the
    safe choice. Grey-level texture is not detected.
    """
    if config.lambda_ is not None and config.clip is not None:
        return Stiffness(config.lambda_, config.clip, None, "given")
    spread = chroma_spread(views)
    if spatially_varying:
        (lam, clip), reason = SOFT, "mesh colors model the texture"
    elif spread > TEXTURED:
        (lam, clip), reason = STIFF, "a constant material cannot explain the frames' colour variation"
    else:
        (lam, clip), reason = SOFT, "the frames' colours are uniform"
    given = config.lambda_ is not None or config.clip is not None
    return Stiffness(config.lambda_ if config.lambda_ is not None else lam,
                     config.clip if config.clip is not None else clip, spread,
                     reason + (" (one value given)" if given else ""))
