"""Resampling frames to an ideal pinhole camera: no lens distortion, square pixels.

The renderer needs both. The OpenCV model maps a normalised pinhole point (x, y) to its
distorted position; each output pixel looks up the source pixel it came from (a forward
map, so no inversion is needed) and is interpolated with ``scipy.ndimage.map_coordinates``.
The output keeps the image size and principal point with f = sqrt(fx fy); pixels whose
source falls outside the frame repeat the nearest edge pixel."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .model import Camera

SQUARE_TOLERANCE = 1e-3  # relative fx/fy difference the renderer accepts


def distort(xy: np.ndarray, d: dict) -> np.ndarray:
    """OpenCV distortion of normalised points (..., 2) with k1 k2 k3 p1 p2."""
    x, y = xy[..., 0], xy[..., 1]
    k1, k2, k3, p1, p2 = (d.get(k, 0.0) for k in ("k1", "k2", "k3", "p1", "p2"))
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return np.stack([x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                     y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], -1)


def undistort_points(xy: np.ndarray, d: dict, iterations: int = 30) -> np.ndarray:
    """Inverse of :func:`distort` by fixed-point iteration (moderate distortion)."""
    xy = np.asarray(xy, dtype=np.float64)
    out = xy.copy()
    for _ in range(iterations):
        out = out + (xy - distort(out, d))
    return out


def needs_resampling(camera: Camera) -> bool:
    return any(camera.distortion.values()) or abs(camera.fx - camera.fy) > SQUARE_TOLERANCE * camera.fx


def pinhole(camera: Camera) -> Camera:
    """The ideal camera frames of ``camera`` are resampled to."""
    f = float(np.sqrt(camera.fx * camera.fy))
    return Camera(camera.width, camera.height, f, f, camera.cx, camera.cy, camera.camera_to_world.copy())


def source_coordinates(camera: Camera) -> np.ndarray:
    """For each pixel of ``pinhole(camera)``, its (row, col) array coordinates in the source."""
    target = pinhole(camera)
    v, u = np.mgrid[0:target.height, 0:target.width] + 0.5  # pixel centres
    xy = np.stack([(u - target.cx) / target.fx, (v - target.cy) / target.fy], -1)
    xy = distort(xy, camera.distortion)
    return np.stack([camera.fy * xy[..., 1] + camera.cy - 0.5, camera.fx * xy[..., 0] + camera.cx - 0.5])


def resample(image: np.ndarray, camera: Camera, order: int = 1) -> np.ndarray:
    """``image`` (H x W or H x W x C) as seen by ``pinhole(camera)``; order 0 for labels."""
    coords = source_coordinates(camera)
    if image.ndim == 2:
        return ndimage.map_coordinates(image, coords, order=order, mode="nearest")
    return np.stack([ndimage.map_coordinates(image[..., c], coords, order=order, mode="nearest")
                     for c in range(image.shape[-1])], -1)
