"""The environment-map convention shared with the backend (bpy-free).

An equirectangular map is placed exactly as Blender's World does with Generated texture
coordinates -> Mapping (Point, rotation Z) -> Environment Texture -> Background (strength):
a world direction d looks up u = 0.5 - atan2(d'y, d'x) / 2pi, v = acos(d'z) / pi (v = 0 is
the top row), d' = Rz(rotation_z_deg) d. See docs/capture-format.md."""

from __future__ import annotations

import math

import numpy as np


def rotation_z(degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def direction_to_uv(d, rotation_z_deg: float = 0.0) -> tuple[float, float]:
    """Texture coordinates (u in [0, 1), v in [0, 1], v = 0 at the top) seen along ``d``."""
    d = rotation_z(rotation_z_deg) @ np.asarray(d, dtype=float)
    d = d / np.linalg.norm(d)
    u = (0.5 - math.atan2(d[1], d[0]) / (2 * math.pi)) % 1.0
    return u, math.acos(max(-1.0, min(1.0, d[2]))) / math.pi


def uv_to_direction(u: float, v: float, rotation_z_deg: float = 0.0) -> np.ndarray:
    """The world direction (unit vector) that looks up ``(u, v)``."""
    phi, theta = 2 * math.pi * (0.5 - u), math.pi * v
    d = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
    return rotation_z(rotation_z_deg).T @ d

