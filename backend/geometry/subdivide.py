"""Midpoint 1-to-4 subdivision (exact: original vertices keep their positions and indices)."""

from __future__ import annotations

import numpy as np

from .mesh import Mesh


def midpoint(mesh: Mesh) -> tuple[Mesh, np.ndarray]:
    """Split every triangle into four at its edge midpoints.

    Returns the new mesh and ``parents`` (E, 2): the two original vertices of each new
    vertex (new vertex ``V + i`` is the midpoint of ``parents[i]``). Face ``4 f + k`` of the
    result lies inside original face ``f`` (k = 0, 1, 2 at its corners, 3 in the middle).
    Per-vertex colours and attributes are interpolated linearly."""
    f = mesh.faces
    V = mesh.n_vertices
    e = np.sort(np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], 1), axis=2)  # (F, 3, 2)
    parents, inverse = np.unique(e.reshape(-1, 2), axis=0, return_inverse=True)
    mid = V + inverse.reshape(-1, 3)  # midpoints of edges 01, 12, 20
    a, b, c = f.T
    ab, bc, ca = mid.T
    faces = np.stack([np.c_[a, ab, ca], np.c_[b, bc, ab], np.c_[c, ca, bc], np.c_[ab, bc, ca]], 1).reshape(-1, 3)

    def extend(values):
        values = np.asarray(values)
        return np.concatenate([values, 0.5 * (values[parents[:, 0]] + values[parents[:, 1]])]).astype(values.dtype)

    out = Mesh(extend(mesh.vertices), faces,
               None if mesh.vertex_colors is None else extend(mesh.vertex_colors),
               {k: extend(v) for k, v in mesh.attributes.items()})
    return out, parents
