"""Procedural test content the project makes itself: an object, an albedo pattern, a sky."""

from __future__ import annotations

import numpy as np

from ..geometry.mesh import Mesh
from ..geometry.primitives import icosphere  # noqa: F401  (re-exported: synth.procedural.icosphere)


def blob(subdivisions: int = 5) -> Mesh:
    """The built-in demo object: a smooth, lumpy, non-convex shape about 1 unit across (Z up)."""
    mesh = icosphere(subdivisions)
    d = mesh.vertices
    x, y, z = d.T
    r = (1.0 + 0.18 * np.sin(3 * x + 1.0) * np.cos(2 * y) + 0.12 * np.cos(4 * z + 0.5)
         - 0.22 * np.exp(-8 * ((x - 0.6) ** 2 + (y + 0.5) ** 2 + (z - 0.4) ** 2)))
    mesh.vertices = d * r[:, None] * np.array([0.55, 0.45, 0.5])
    return mesh


def albedo_pattern(points: np.ndarray, scale: float = 6.0) -> np.ndarray:
    """A smooth, colourful albedo pattern (stripes and blotches) in [0.1, 0.8]."""
    p = np.asarray(points) * scale
    s1 = 0.5 + 0.5 * np.sin(p[:, 0] + 0.7 * np.sin(p[:, 2]))
    s2 = 0.5 + 0.5 * np.cos(p[:, 1] * 0.8 + p[:, 2] * 0.6)
    c1, c2, c3 = np.array([0.75, 0.35, 0.12]), np.array([0.15, 0.45, 0.7]), np.array([0.8, 0.75, 0.6])
    col = s1[:, None] * c1 + (1 - s1[:, None]) * c2
    col = s2[:, None] * col + (1 - s2[:, None]) * c3
    return np.clip(col, 0.1, 0.8).astype(np.float32)


def sky(width: int = 256, sun_elevation_deg: float = 35.0, sun_azimuth_deg: float = 40.0,
        sun_radiance: float = 400.0, sun_size_deg: float = 4.0) -> np.ndarray:
    """An equirectangular HDR sky (Blender's mapping) with a warm sun, blue sky and grey ground."""
    height = width // 2
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    phi = np.pi * (1.0 - 2.0 * u)  # atan2(y, x) for the Blender lookup u = 0.5 - phi / 2pi
    theta = np.pi * v
    d = np.stack([np.sin(theta)[:, None] * np.cos(phi)[None, :],
                  np.sin(theta)[:, None] * np.sin(phi)[None, :],
                  np.repeat(np.cos(theta)[:, None], width, 1)], -1)
    el, az = np.radians(sun_elevation_deg), np.radians(sun_azimuth_deg)
    sun = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    up = np.clip(d[..., 2], 0, 1)[..., None]
    img = (1 - up) * np.array([0.9, 0.85, 0.8]) + up * np.array([0.35, 0.55, 1.0])
    img = np.where(d[..., 2:3] < 0, np.array([0.3, 0.28, 0.25]), img)
    cos_sun = d @ sun
    glow = np.exp((cos_sun - 1) * 30)[..., None] * np.array([1.5, 1.2, 0.8])
    disc = (cos_sun > np.cos(np.radians(sun_size_deg / 2)))[..., None] * sun_radiance * np.array([1.0, 0.9, 0.75])
    return (img + glow + disc).astype(np.float32)
