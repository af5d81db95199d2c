"""A mesh file given by the user: checked, repaired where possible, simplified to the budget."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...capture.model import Camera
from ...errors import require
from ..mesh import Mesh, load_mesh
from ..simplify import simplify
from ..topology import clean, enclosed, inspect, orient_outward, repair

FIX = "give a closed triangle mesh in the capture's world frame, or use --init carve"


def in_view_share(mesh: Mesh, cameras: list[Camera], min_view_share: float = 0.5) -> float:
    """Share of vertices inside the cameras' common view: in front of and inside the frame of
    at least ``min_view_share`` of the cameras. (A mesh far away along one camera's axis is
    inside that camera's frustum but outside what the capture looks at.)"""
    seen = np.zeros(mesh.n_vertices, np.int64)
    for cam in cameras:
        uv, depth = cam.project(mesh.vertices)
        seen += (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height)
    need = max(1, int(np.ceil(min_view_share * len(cameras))))
    return float(np.mean(seen >= need)) if len(seen) else 0.0


def check_initial_mesh(mesh: Mesh, path, cameras: list[Camera], warn) -> Mesh:
    """Reject meshes that cannot start a reconstruction; repair the rest (with a warning)."""
    require(mesh.n_faces > 0 and mesh.n_vertices >= 4, path, "the initial mesh is empty", FIX)
    require(bool(np.all(np.isfinite(mesh.vertices))), path, "the initial mesh has NaN or Inf vertices", FIX)
    require(int(mesh.faces.min()) >= 0 and int(mesh.faces.max()) < mesh.n_vertices, path,
            "the initial mesh's faces index missing vertices", FIX)
    mesh = clean(mesh)
    require(mesh.n_faces >= 4 and float(mesh.face_areas().sum()) > 0, path,
            "the initial mesh has no surface area", FIX)
    share = in_view_share(mesh, cameras)
    require(share > 0, path, "the initial mesh lies outside the cameras' common view (no vertex is in the frame "
            "of half the cameras)",
            "check the mesh's position, units and up axis against the capture, or use --init carve")
    if share < 0.5:
        warn(f"{Path(str(path)).name}: only {100 * share:.0f}% of the initial mesh is in the cameras' common view")
    report = inspect(mesh)
    if not report.closed_manifold:
        mesh, notes = repair(mesh)
        after = inspect(mesh)
        require(mesh.n_faces >= 4, path, "the initial mesh has nothing left after repair", FIX)
        warn(f"{Path(str(path)).name}: initial mesh repaired ({', '.join(report.issues)}: "
             f"{', '.join(notes) or 'cleaned'}"
             + ("" if after.closed_manifold else f"; still {', '.join(after.issues)}") + ")")
    inside = int(enclosed(mesh, [c.centre for c in cameras]).sum())
    require(inside == 0, path, f"the initial mesh encloses {inside} of the {len(cameras)} cameras "
            "(the renderer must see it from outside)",
            "give an initial mesh that leaves every camera outside it (check its scale and units), "
            "or choose another --init")
    return orient_outward(mesh)


def user_mesh(path: str | Path, cameras: list[Camera], faces: int, warn) -> Mesh:
    """Load, check and repair ``path``; simplify it to ``faces`` faces if it has more."""
    mesh = check_initial_mesh(load_mesh(path), path, cameras, warn)
    return simplify(mesh, faces)
