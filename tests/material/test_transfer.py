"""Carrying a per-vertex material onto another surface (material/transfer.py)."""

from __future__ import annotations

import numpy as np

from backend.geometry.primitives import icosphere
from backend.geometry.subdivide import midpoint
from backend.material.transfer import carry_vertex_material


def _painted(mesh):
    x = mesh.vertices
    mesh.vertex_colors = np.stack([0.5 + 0.4 * x[:, 0], 0.5 + 0.3 * x[:, 1], 0.2 + 0.1 * x[:, 2]], 1)
    mesh.attributes["specular"] = (0.3 + 0.2 * x[:, 2]).astype(np.float32)
    mesh.attributes["roughness"] = np.full(len(x), 0.4, np.float32)
    return mesh


def test_a_material_carried_onto_its_own_mesh_is_unchanged():
    source = _painted(icosphere(2))
    out = carry_vertex_material(source, icosphere(2))
    np.testing.assert_allclose(out.vertex_colors, source.vertex_colors, atol=1e-9)
    np.testing.assert_allclose(out.attributes["specular"], source.attributes["specular"], atol=1e-6)


def test_midpoints_get_the_mean_of_their_edge_and_the_target_keeps_its_shape():
    source = _painted(icosphere(1))
    fine, _ = midpoint(icosphere(1))
    out = carry_vertex_material(source, fine)
    np.testing.assert_array_equal(out.vertices, fine.vertices)
    # a midpoint vertex lies on an edge of the source: linear interpolation of its two ends
    a, b = source.faces[0, 0], source.faces[0, 1]
    mid = int(np.argmin(np.linalg.norm(fine.vertices - 0.5 * (source.vertices[a] + source.vertices[b]), axis=1)))
    np.testing.assert_allclose(out.vertex_colors[mid], 0.5 * (source.vertex_colors[a] + source.vertex_colors[b]),
                               atol=1e-9)
    assert out.attributes["roughness"].shape == (fine.n_vertices,)
