"""Small analytic meshes for the metric tests."""

from __future__ import annotations

import numpy as np

from backend.geometry.mesh import Mesh


def square(lo: float = 0.0, hi: float = 1.0, z: float = 0.0, fan: bool = False) -> Mesh:
    """A square [lo, hi]^2 at height z: two triangles, or four around the centre (fan)."""
    corners = [[lo, lo, z], [hi, lo, z], [hi, hi, z], [lo, hi, z]]
    if not fan:
        return Mesh(corners, [[0, 1, 2], [0, 2, 3]])
    c = 0.5 * (lo + hi)
    return Mesh(corners + [[c, c, z]], [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])


def blob(n_lat: int = 24, n_lon: int = 48) -> Mesh:
    """A closed, lopsided sphere with no symmetry, for alignment tests."""
    theta = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    r = 1 + 0.3 * d[:, 0] + 0.2 * d[:, 1] * d[:, 2] + 0.15 * d[:, 2] ** 3
    verts = np.vstack([d * r[:, None] * [1.0, 0.7, 0.5], [[0, 0, 0.5 * 1.15]], [[0, 0, -0.5 * 0.85]]])
    top, bottom = len(verts) - 2, len(verts) - 1
    idx = np.arange(len(theta) * len(phi)).reshape(len(theta), len(phi))
    faces = []
    for j in range(n_lon):
        k = (j + 1) % n_lon
        faces.append([top, idx[0, j], idx[0, k]])
        faces.append([bottom, idx[-1, k], idx[-1, j]])
        for i in range(len(theta) - 1):
            faces += [[idx[i, j], idx[i + 1, j], idx[i + 1, k]], [idx[i, j], idx[i + 1, k], idx[i, k]]]
    return Mesh(verts, faces)


def similarity(angle_deg: float, axis, scale: float, translation) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.radians(angle_deg)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rot = np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k
    m = np.eye(4)
    m[:3, :3] = scale * rot
    m[:3, 3] = translation
    return m
