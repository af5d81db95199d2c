"""Resampling distorted, non-square-pixel frames to an ideal pinhole camera."""

from __future__ import annotations

import numpy as np

from backend.capture.model import Camera
from backend.capture.undistort import distort, needs_resampling, pinhole, resample, undistort_points

DIST = {"k1": -0.18, "k2": 0.04, "p1": 0.002, "p2": -0.0015}


def pattern(xy: np.ndarray) -> np.ndarray:
    """A smooth function of the ray direction (normalised pinhole coordinates)."""
    return np.sin(6 * xy[..., 0]) * np.cos(5 * xy[..., 1]) + xy[..., 0]


def pixel_rays(camera: Camera) -> np.ndarray:
    v, u = np.mgrid[0:camera.height, 0:camera.width] + 0.5
    return np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy], -1)


def test_undistort_points_inverts_distort():
    xy = np.random.default_rng(0).uniform(-0.6, 0.6, (500, 2))
    np.testing.assert_allclose(undistort_points(distort(xy, DIST), DIST), xy, atol=1e-10)


def test_resample_matches_an_ideal_camera():
    cam = Camera(160, 120, 150.0, 156.0, 83.2, 58.7, np.eye(4), dict(DIST))
    assert needs_resampling(cam)
    # What the real lens records: each pixel sees the ray its distorted position undistorts to.
    distorted = pattern(undistort_points(pixel_rays(cam), DIST))
    target = pinhole(cam)
    assert target.fx == target.fy and not target.distortion and not needs_resampling(target)
    assert (target.width, target.height, target.cx, target.cy) == (cam.width, cam.height, cam.cx, cam.cy)
    out = resample(np.dstack([distorted, -distorted]), cam)
    expected = pattern(pixel_rays(target))
    inner = (slice(8, -8), slice(8, -8))  # away from edge pixels the source does not cover
    assert np.abs(out[..., 0] - expected)[inner].max() < 0.003  # a half-pixel slip gives 0.02
    np.testing.assert_array_equal(out[..., 1], -out[..., 0])
    # Labels keep their values with nearest-neighbour lookup.
    labels = resample(np.round(distorted * 3), cam, order=0)
    assert set(np.unique(labels)) <= set(np.unique(np.round(distorted * 3)))


def test_square_pinhole_needs_nothing():
    cam = Camera(32, 24, 40.0, 40.02, 16, 12, np.eye(4))
    assert not needs_resampling(cam)
