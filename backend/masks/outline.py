"""A mask's outline moved onto the frame's own edges: a band-limited GrabCut round on the
unblurred frame, then a colour guided filter of the mask.

The visual hull is the intersection of every view's cone, so a pixel one mask misses at the
object's outline cuts the object in 3-D, while a pixel it adds is usually cut away by another
view. GrabCut on a blurred frame (the blur keeps sensor noise from merging the colour models)
places the outline a pixel or two off the image's edge. A last GrabCut round, sure of
everything farther than ``grabcut_band`` pixels from the outline, re-decides the band on the
frame's own colours (no blur: the colour models come from the whole box, so noise averages out
there, and only the band's labels can move). The guided filter (He, Sun and Tang,
"Guided Image Filtering", 2013) fits, in every window of ``(2 r + 1)^2`` pixels, the mask as an
affine function of the colour,

    q_i = a_k^T I_i + b_k,   a_k = (Sigma_k + eps U)^-1 cov_k(I, p),   b_k = mean_k(p) - a_k^T mean_k(I),

averages ``a`` and ``b`` over the windows holding each pixel, and reads the outline where the
filtered mask crosses ``level``. Where the frame has an edge near the outline, the crossing
follows that edge; where it has none (``eps`` dominates ``Sigma``) the filter is a box blur and the
outline stays. Only pixels within ``band`` of the outline may change; the pieces are then kept as
``segment.keep_pieces`` keeps them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .segment import grabcut, keep_pieces, mask_seeds


@dataclass
class OutlineOptions:
    grabcut_band: int = 2  # the GrabCut round's undecided band on each side (pixels); 0: no round
    grabcut_iterations: int = 5
    radius: int = 4  # guided filter window half side (pixels)
    eps: float = 1e-3  # regulariser on the colour covariance (colours in [0, 1])
    level: float = 0.4  # filtered mask value at the outline; below 0.5 leans to foreground (a missed pixel cuts the hull)
    band: int = 3  # pixels from the outline that may change label


def _box(x: np.ndarray, r: int) -> np.ndarray:
    import cv2  # bpy must be imported before cv2 in one process

    return cv2.boxFilter(x, -1, (2 * r + 1, 2 * r + 1), normalize=True, borderType=cv2.BORDER_REFLECT)


def guided_filter(rgb: np.ndarray, p: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """``p`` (HxW float) filtered with the colour guide ``rgb`` (HxWx3 uint8 or float in [0, 1])."""
    I = np.asarray(rgb, np.float32)
    if I.max(initial=0.0) > 1.5:
        I = I / 255.0
    p = np.asarray(p, np.float32)
    r = int(radius)
    mean_I = np.stack([_box(I[..., c], r) for c in range(3)], -1)
    mean_p = _box(p, r)
    cov_Ip = np.stack([_box(I[..., c] * p, r) for c in range(3)], -1) - mean_I * mean_p[..., None]
    sigma = np.empty(I.shape[:2] + (3, 3), np.float32)
    for a in range(3):
        for b in range(a, 3):
            s = _box(I[..., a] * I[..., b], r) - mean_I[..., a] * mean_I[..., b]
            sigma[..., a, b] = sigma[..., b, a] = s
    sigma += eps * np.eye(3, dtype=np.float32)
    coef = np.linalg.solve(sigma, cov_Ip[..., None])[..., 0]
    offset = mean_p - np.einsum("hwc,hwc->hw", coef, mean_I)
    mean_a = np.stack([_box(np.ascontiguousarray(coef[..., c]), r) for c in range(3)], -1)
    return np.einsum("hwc,hwc->hw", mean_a, I) + _box(offset, r)


def refine_outline(rgb: np.ndarray, mask: np.ndarray, options: OutlineOptions | None = None,
                   keep_uv: np.ndarray | None = None) -> np.ndarray:
    """``mask`` (float 0/1) with its outline moved onto ``rgb``'s edges (module docstring);
    float32 0/1. Filters only the box round the outline, so its cost is the object's, not the frame's."""
    import cv2  # bpy must be imported before cv2 in one process

    options = options or OutlineOptions()
    m = (np.asarray(mask) > 0.5).astype(np.uint8)
    if not m.any() or m.all():
        return m.astype(np.float32)
    if options.grabcut_band > 0:
        labels = mask_seeds(m.shape, m, options.grabcut_band)
        m = (grabcut(rgb, labels, options.grabcut_iterations, keep_uv, 0.0) > 0.5).astype(np.uint8)
        if not m.any():
            return m.astype(np.float32)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * options.band + 1, 2 * options.band + 1))
    near = cv2.dilate(m, kernel) > cv2.erode(m, kernel)
    ys, xs = np.nonzero(near)
    pad = 2 * options.radius + 2
    y0, y1 = max(0, ys.min() - pad), min(m.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(m.shape[1], xs.max() + pad + 1)
    q = guided_filter(np.asarray(rgb)[y0:y1, x0:x1], m[y0:y1, x0:x1].astype(np.float32), options.radius, options.eps)
    out = m.copy()
    crop = out[y0:y1, x0:x1]
    band = near[y0:y1, x0:x1]
    crop[band] = (q[band] >= options.level).astype(np.uint8)
    return keep_pieces(out, keep_uv)
