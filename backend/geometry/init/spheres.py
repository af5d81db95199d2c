"""Sphere cloud: a union of spheres packed inside the visual hull (the paper's general option).

Spheres are placed greedily at the hull voxel farthest from the hull's boundary that no
sphere covers yet, with that distance as radius, until they fill ``coverage`` of the hull's
volume (or ``max_spheres`` is reached). The union is meshed as the zero level set of
max_i (r_i - |x - c_i|), so it is closed and manifold; it lies inside the hull and is
smoother than it, which leaves the silhouettes to the optimisation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ...capture.model import Capture
from ..isosurface import marching_tetrahedra
from ..mesh import Mesh
from ..simplify import simplify
from ..topology import keep_largest_components
from .hull import HullConfig, visual_hull


@dataclass
class SphereCloudConfig:
    grid: int = 64  # hull grid cells along its longest side
    coverage: float = 0.9  # share of the hull volume the spheres must cover
    max_spheres: int = 96
    min_radius_cells: float = 1.5  # smaller spheres are not worth placing


def pack_spheres(inside: np.ndarray, spacing: float, origin: np.ndarray,
                 config: SphereCloudConfig) -> tuple[np.ndarray, np.ndarray]:
    """Greedy sphere packing of a boolean voxel grid: (centres (n, 3), radii (n,))."""
    depth = ndimage.distance_transform_edt(inside)  # cells to the nearest outside voxel
    idx = np.stack(np.nonzero(inside), -1)
    d = depth[inside]
    covered = np.zeros(len(idx), bool)
    centres, radii = [], []
    while len(radii) < config.max_spheres and covered.mean() < config.coverage:
        free = np.where(covered, -1.0, d)
        best = int(np.argmax(free))
        r = d[best]
        if free[best] < config.min_radius_cells:
            break
        c = idx[best]
        covered |= np.sum((idx - c) ** 2, 1) <= r * r
        centres.append(origin + spacing * c)
        radii.append(spacing * r)
    return np.array(centres).reshape(-1, 3), np.array(radii)


def union_of_spheres(centres: np.ndarray, radii: np.ndarray, spacing: float) -> Mesh:
    """The boundary of the union of spheres, meshed on a grid of the given spacing."""
    lo = (centres - radii[:, None]).min(0) - 2 * spacing
    hi = (centres + radii[:, None]).max(0) + 2 * spacing
    shape = tuple(int(np.ceil((hi[i] - lo[i]) / spacing)) + 1 for i in range(3))
    axes = [lo[i] + spacing * np.arange(shape[i]) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    field = np.full(len(pts), -np.inf)
    for c, r in zip(centres, radii):
        np.maximum(field, r - np.linalg.norm(pts - c, axis=1), out=field)
    return marching_tetrahedra(field.reshape(shape), 0.0, lo, spacing)


def sphere_cloud(capture: Capture, faces: int = 5000, config: SphereCloudConfig | None = None) -> Mesh:
    config = config or SphereCloudConfig()
    hull = visual_hull(capture, HullConfig(grid=config.grid))
    centres, radii = pack_spheres(hull.largest_part(), hull.spacing, hull.origin, config)
    if len(radii) == 0:  # a hull thinner than the smallest sphere: fall back to its voxels
        centres, radii = hull.points()[hull.inside.ravel()], np.full(int(hull.inside.sum()), hull.spacing)
    mesh = union_of_spheres(centres, radii, hull.spacing / 2)
    return simplify(keep_largest_components(mesh, 0.01), faces)
