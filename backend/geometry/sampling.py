"""Area-uniform samples of a mesh's surface, and per-vertex values read at them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mesh import Mesh


@dataclass
class SurfaceSamples:
    points: np.ndarray  # (N, 3) float64
    faces: np.ndarray  # (N,) int64, the face each point lies on
    barycentric: np.ndarray  # (N, 3) float64 weights of that face's vertices


def sample_surface(mesh: Mesh, n: int, seed: int = 0) -> SurfaceSamples:
    """``n`` points uniformly distributed over the surface (faces chosen by area).

    Deterministic for a given mesh, ``n`` and ``seed``. Raises ValueError for a mesh
    without surface area."""
    areas = mesh.face_areas()
    cdf = np.cumsum(areas)
    if not len(cdf) or not np.isfinite(cdf[-1]) or cdf[-1] <= 0:
        raise ValueError("mesh has no surface area")
    rng = np.random.default_rng(seed)
    faces = np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right")
    faces = np.minimum(faces, len(cdf) - 1)
    r = rng.random((n, 2))
    flip = r.sum(1) > 1
    r[flip] = 1 - r[flip]
    bary = np.column_stack([1 - r[:, 0] - r[:, 1], r[:, 0], r[:, 1]])
    corners = mesh.vertices[mesh.faces[faces]]  # (N, 3 corners, 3)
    points = np.einsum("nk,nkd->nd", bary, corners)
    return SurfaceSamples(points, faces, bary)


def interpolate(mesh: Mesh, values: np.ndarray, samples: SurfaceSamples) -> np.ndarray:
    """Per-vertex ``values`` (V, C) interpolated at surface samples -> (N, C)."""
    corner_values = np.asarray(values, dtype=np.float64)[mesh.faces[samples.faces]]
    return np.einsum("nk,nkc->nc", samples.barycentric, corner_values)
