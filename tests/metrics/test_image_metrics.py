"""PSNR, SSIM and RMSE against hand-derived values."""

import math

import numpy as np
import pytest

from backend.capture.images import srgb_to_linear
from backend.metrics import image as im


def rng_image(shape, seed=0):
    return np.random.default_rng(seed).random(shape)


def test_identical_images():
    a = rng_image((24, 20, 3))
    assert im.psnr(a, a) == math.inf
    assert im.ssim(a, a) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("sigma", [0.1, 0.02])
def test_psnr_of_known_noise_in_srgb(sigma):
    # sRGB values 0.5 +- sigma (random signs): MSE = sigma^2 exactly, after decoding to
    # linear and letting psnr() encode back
    rng = np.random.default_rng(1)
    target_srgb = np.full((32, 32, 3), 0.5)
    pred_srgb = target_srgb + sigma * rng.choice([-1.0, 1.0], size=target_srgb.shape)
    value = im.psnr(srgb_to_linear(pred_srgb), srgb_to_linear(target_srgb))
    assert value == pytest.approx(-10 * math.log10(sigma ** 2), abs=1e-3)


def test_psnr_linear_and_clipping():
    target = np.full((8, 8, 3), 0.25)
    pred = target + 0.05
    assert im.psnr(pred, target, srgb=False) == pytest.approx(-20 * math.log10(0.05))
    # sRGB comparison clips: values above 1 look the same as 1
    assert im.psnr(np.full((8, 8, 3), 3.0), np.ones((8, 8, 3))) == math.inf


def test_masked_psnr_uses_mask_pixels_only():
    target = np.zeros((10, 10, 3))
    pred = target.copy()
    mask = np.zeros((10, 10))
    mask[2:5, 2:7] = 1
    pred[mask == 0] = 0.7  # errors outside the mask do not count
    assert im.psnr(pred, target, mask, srgb=False) == math.inf
    pred[mask == 1] = 0.1
    assert im.psnr(pred, target, mask, srgb=False) == pytest.approx(20.0)
    with pytest.raises(ValueError):
        im.psnr(pred, target, np.zeros((10, 10)))
    with pytest.raises(ValueError):
        im.psnr(pred, target, np.ones((5, 5)))


@pytest.mark.parametrize("a,b", [(0.2, 0.6), (0.5, 0.5), (0.0, 1.0)])
def test_ssim_of_constant_images(a, b):
    # no variance: SSIM = (2ab + C1) / (a^2 + b^2 + C1) everywhere
    c1 = 0.01 ** 2
    expected = (2 * a * b + c1) / (a * a + b * b + c1)
    value = im.ssim(np.full((16, 16), a), np.full((16, 16), b), srgb=False)
    assert value == pytest.approx(expected, rel=1e-9)


def reference_ssim_at(x, y, i, j):
    """SSIM at pixel (i, j) from an explicit 11 x 11 Gaussian window (Wang et al. 2004)."""
    r = np.arange(-5, 6)
    g = np.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * 1.5 ** 2))
    w = g / g.sum()
    px, py = x[i - 5:i + 6, j - 5:j + 6], y[i - 5:i + 6, j - 5:j + 6]
    mx, my = (w * px).sum(), (w * py).sum()
    vx, vy = (w * (px - mx) ** 2).sum(), (w * (py - my) ** 2).sum()
    cov = (w * (px - mx) * (py - my)).sum()
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    return (2 * mx * my + c1) * (2 * cov + c2) / ((mx ** 2 + my ** 2 + c1) * (vx + vy + c2))


def test_ssim_matches_an_explicit_window_computation():
    x = rng_image((17, 19, 3), seed=2)
    y = np.clip(0.8 * x + 0.3 * rng_image((17, 19, 3), seed=3), 0, 1)
    interior = [(i, j) for i in range(5, 12) for j in range(5, 14)]
    per_channel = [[reference_ssim_at(x[..., c], y[..., c], i, j) for i, j in interior] for c in range(3)]
    ref = np.mean(per_channel, axis=0)
    smap = im.ssim_map(x, y, srgb=False)
    assert np.allclose([smap[i, j] for i, j in interior], ref, atol=1e-12)
    assert im.ssim(x, y, srgb=False) == pytest.approx(ref.mean(), abs=1e-12)
    assert 0.2 < ref.mean() < 0.95  # a non-trivial case
    # a mask restricts the mean to its (interior) pixels
    mask = np.zeros((17, 19))
    mask[6:9, 7:12] = 1
    masked_ref = np.mean([r for (i, j), r in zip(interior, ref) if mask[i, j]])
    assert im.ssim(x, y, mask, srgb=False) == pytest.approx(masked_ref, abs=1e-12)


def test_ssim_srgb_default_encodes_both_images():
    x = rng_image((16, 16, 3), seed=4)
    y = rng_image((16, 16, 3), seed=5)
    assert im.ssim(srgb_to_linear(x), srgb_to_linear(y)) == pytest.approx(im.ssim(x, y, srgb=False), abs=1e-5)
    with pytest.raises(ValueError):
        im.ssim(np.zeros((8, 30)), np.zeros((8, 30)))


def test_rmse_and_albedo_rmse():
    gt = rng_image((100, 3), seed=6)
    assert im.rmse(gt + 0.1, gt) == pytest.approx(0.1)
    assert im.albedo_rmse(gt, gt) == 0
    pred = gt * [0.5, 2.0, 1.0]
    assert im.albedo_rmse(pred, gt) == pytest.approx(math.sqrt(np.mean((pred - gt) ** 2)))
    assert im.albedo_rmse(pred, gt, fit_scale=True) == pytest.approx(0, abs=1e-12)
    weights = np.r_[np.ones(50), np.zeros(50)]
    off = gt.copy()
    off[50:] += 1
    assert im.rmse(off, gt, weights) == 0


def test_image_metrics_per_view_and_mean():
    targets = [rng_image((16, 16, 3), seed=s) for s in (7, 8)]
    preds = [targets[0], np.clip(targets[1] + 0.05, 0, 1)]
    masks = [np.ones((16, 16)), np.ones((16, 16))]
    out = im.image_metrics(preds, targets, masks, srgb=False)
    assert out["views"][0] == {"psnr": math.inf, "ssim": pytest.approx(1.0)}
    assert out["views"][1]["psnr"] == pytest.approx(im.psnr(preds[1], targets[1], srgb=False))
    assert out["ssim"] == pytest.approx(np.mean([v["ssim"] for v in out["views"]]))
    assert out["psnr"] == math.inf
    with pytest.raises(ValueError):
        im.image_metrics(preds, targets[:1])
