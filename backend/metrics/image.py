"""Image metrics: PSNR and SSIM of renders against photographs, albedo RMSE.

Images are linear float RGB (H, W, 3) as :mod:`backend.capture.images` reads them. By
default (``srgb=True``, as in the paper) both images are clipped to [0, 1] and sRGB-encoded
before comparison, so the scores describe what a viewer sees and match scores computed on
8-bit PNGs; ``srgb=False`` compares the linear values as given, with peak value 1.

A mask (H, W) in [0, 1] restricts a score to the object: it weights each pixel (a binary
mask selects pixels; soft edges count partially)."""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter

from ..capture.images import linear_to_srgb

SSIM_SIGMA = 1.5
SSIM_RADIUS = 5  # an 11 x 11 Gaussian window
SSIM_K1, SSIM_K2 = 0.01, 0.03


def _prepare(pred, target, mask, srgb: bool):
    pred = np.asarray(pred, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if pred.shape != target.shape:
        raise ValueError(f"image shapes differ: {pred.shape} vs {target.shape}")
    if pred.ndim == 2:
        pred, target = pred[..., None], target[..., None]
    if srgb:
        pred = linear_to_srgb(pred).astype(np.float64)
        target = linear_to_srgb(target).astype(np.float64)
    weights = np.ones(pred.shape[:2]) if mask is None else np.asarray(mask, dtype=np.float64)
    if weights.shape != pred.shape[:2]:
        raise ValueError(f"mask shape {weights.shape} does not match image {pred.shape[:2]}")
    return pred, target, np.clip(weights, 0.0, 1.0)


def _weighted_mean(values: np.ndarray, weights: np.ndarray) -> float:
    total = weights.sum()
    if total <= 0:
        raise ValueError("mask is empty")
    return float((values * weights).sum() / total)


def psnr(pred, target, mask=None, srgb: bool = True) -> float:
    """Peak signal-to-noise ratio in dB (peak 1); ``inf`` for identical images.

    The mean squared error runs over all channels of the (mask-weighted) pixels."""
    pred, target, w = _prepare(pred, target, mask, srgb)
    mse = _weighted_mean(((pred - target) ** 2).mean(-1), w)
    return math.inf if mse == 0 else float(-10.0 * math.log10(mse))


def ssim_map(pred, target, srgb: bool = True) -> np.ndarray:
    """Per-pixel SSIM (Wang et al. 2004), averaged over channels -> (H, W).

    Gaussian window (sigma 1.5, 11 x 11), K1 = 0.01, K2 = 0.03, dynamic range 1, population
    statistics; image borders are reflected."""
    pred, target, _ = _prepare(pred, target, None, srgb)
    c1, c2 = SSIM_K1 ** 2, SSIM_K2 ** 2
    truncate = SSIM_RADIUS / SSIM_SIGMA
    maps = []
    for c in range(pred.shape[-1]):
        x, y = pred[..., c], target[..., c]

        def blur(a):
            return gaussian_filter(a, SSIM_SIGMA, truncate=truncate, mode="reflect")

        mx, my = blur(x), blur(y)
        vx = blur(x * x) - mx * mx
        vy = blur(y * y) - my * my
        cxy = blur(x * y) - mx * my
        maps.append((2 * mx * my + c1) * (2 * cxy + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2)))
    return np.mean(maps, axis=0)


def ssim(pred, target, mask=None, srgb: bool = True) -> float:
    """Mean SSIM; 1 for identical images.

    As in the reference implementation the mean leaves out the 5-pixel border where the
    window overhangs the image; with a mask it is the mask-weighted mean of the rest."""
    pred, target, w = _prepare(pred, target, mask, False)
    h, wd = w.shape
    if min(h, wd) <= 2 * SSIM_RADIUS:
        raise ValueError(f"image {wd}x{h} is smaller than the {2 * SSIM_RADIUS + 1}-pixel SSIM window")
    inner = np.zeros_like(w)
    inner[SSIM_RADIUS:-SSIM_RADIUS, SSIM_RADIUS:-SSIM_RADIUS] = 1
    return _weighted_mean(ssim_map(pred, target, srgb), w * inner)


def rmse(pred, target, weights=None) -> float:
    """Root-mean-square error over all entries (rows optionally weighted)."""
    pred = np.asarray(pred, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if pred.shape != target.shape:
        raise ValueError(f"shapes differ: {pred.shape} vs {target.shape}")
    sq = (pred - target) ** 2
    sq = sq.reshape(len(sq), -1).mean(1) if sq.ndim > 1 else sq
    w = np.ones(len(sq)) if weights is None else np.asarray(weights, dtype=np.float64)
    return math.sqrt(_weighted_mean(sq, w))


def albedo_rmse(pred_albedo, gt_albedo, fit_scale: bool = False) -> float:
    """RMSE between predicted and true linear albedo (N, 3) at the same surface points.

    ``fit_scale`` first scales each predicted channel by its least-squares factor, for
    captures whose lighting is only known up to scale."""
    pred = np.asarray(pred_albedo, dtype=np.float64)
    gt = np.asarray(gt_albedo, dtype=np.float64)
    if fit_scale:
        denom = (pred * pred).sum(0)
        pred = pred * np.where(denom > 0, (pred * gt).sum(0) / np.where(denom > 0, denom, 1), 1)
    return rmse(pred, gt)


def image_metrics(predicted_images, target_images, masks=None, srgb: bool = True) -> dict:
    """PSNR and SSIM of each predicted image against its target, and their means.

    ``predicted_images`` and ``target_images`` are equally long sequences of linear RGB
    arrays; ``masks`` is None or one (H, W) mask per image. Returns
    ``{"psnr": mean dB, "ssim": mean, "views": [{"psnr": ..., "ssim": ...}, ...]}``
    (the mean PSNR is ``inf`` when any view matches exactly)."""
    predicted_images, target_images = list(predicted_images), list(target_images)
    masks = [None] * len(target_images) if masks is None else list(masks)
    if not (len(predicted_images) == len(target_images) == len(masks)) or not target_images:
        raise ValueError(f"{len(predicted_images)} predicted images, {len(target_images)} targets, "
                         f"{len(masks)} masks: need the same number (at least one)")
    views = [{"psnr": psnr(p, t, m, srgb), "ssim": ssim(p, t, m, srgb)}
             for p, t, m in zip(predicted_images, target_images, masks)]
    return {"psnr": float(np.mean([v["psnr"] for v in views])),
            "ssim": float(np.mean([v["ssim"] for v in views])), "views": views}
