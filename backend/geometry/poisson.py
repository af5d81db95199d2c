"""Screened Poisson surface reconstruction (pymeshlab) from oriented points."""

from __future__ import annotations

import numpy as np

from .mesh import Mesh
from .topology import clean, keep_largest_components, orient_outward


class SurfaceReconstructionError(ValueError):
    """Too few samples, or no surface, to rebuild from: keep the previous surface."""


def depth_for_resolution(extent: float, spacing: float, lo: int = 5, hi: int = 10) -> int:
    """Octree depth whose cells are about ``spacing`` wide over a box ``extent`` across."""
    return int(np.clip(np.ceil(np.log2(max(extent, 1e-12) * 1.1 / max(spacing, 1e-12))), lo, hi))


def poisson(points: np.ndarray, normals: np.ndarray, depth: int = 8, point_weight: float = 4.0,
            min_component_share: float = 0.02) -> Mesh:
    """A closed surface through oriented ``points`` (normals point outward).

    Small spurious components are dropped and the result is wound outward."""
    import pymeshlab

    points = np.ascontiguousarray(points, np.float64)
    normals = np.ascontiguousarray(normals, np.float64)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    if len(points) < 16:
        raise SurfaceReconstructionError(f"only {len(points)} consistent surface samples (16 needed)")
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=points, v_normals_matrix=normals))
    ms.generate_surface_reconstruction_screened_poisson(depth=int(depth), pointweight=point_weight,
                                                        samplespernode=1.5, preclean=True, threads=1)
    m = ms.current_mesh()
    mesh = clean(Mesh(m.vertex_matrix(), m.face_matrix()))
    if mesh.n_faces == 0:
        raise SurfaceReconstructionError("surface reconstruction produced no faces")
    return orient_outward(keep_largest_components(mesh, min_component_share))
