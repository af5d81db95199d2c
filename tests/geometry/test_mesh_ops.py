"""Topology, marching tetrahedra, 1-to-4 subdivision and the face budget."""

from __future__ import annotations

import numpy as np
import pytest

from backend.bench._scenes import torus
from backend.geometry.isosurface import marching_tetrahedra
from backend.geometry.mesh import Mesh
from backend.geometry.simplify import FaceBudget, simplify
from backend.geometry.subdivide import midpoint
from backend.geometry.topology import clean, genus, inspect, orient_outward, repair
from backend.synth.procedural import blob, icosphere


def volume(mesh: Mesh) -> float:
    v = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6)


def test_genus_from_euler_characteristic():
    assert genus(icosphere(2)) == 0
    assert genus(torus()) == 1
    two = Mesh(np.vstack([torus().vertices, torus().vertices + 5]),
               np.vstack([torus().faces, torus().faces + torus().n_vertices]))
    report = inspect(two)
    assert report.components == 2 and report.euler == 0 and report.genus == 2


def test_inspect_finds_defects_and_repair_fixes_them():
    sphere = icosphere(2)
    holed = Mesh(sphere.vertices, sphere.faces[1:])
    assert inspect(holed).boundary_edges == 3 and inspect(holed).genus is None
    # two tetrahedra sharing one vertex: a non-manifold vertex
    t = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    pinched = Mesh(np.vstack([t, -t[1:]]), np.vstack([f, np.where(f == 0, 0, f + 3)[:, ::-1]]))
    assert inspect(pinched).nonmanifold_vertices == 1
    flipped = sphere.copy()
    flipped.faces[:10] = flipped.faces[:10, ::-1]
    assert inspect(flipped).inconsistent_edges > 0
    for bad in (holed, flipped):
        fixed, notes = repair(bad)
        assert notes and inspect(fixed).closed_manifold, inspect(fixed).issues
    inverted = Mesh(sphere.vertices, sphere.faces[:, ::-1])
    assert volume(inverted) < 0 < volume(orient_outward(inverted))


def test_clean_drops_degenerate_duplicate_and_unused():
    m = Mesh(np.vstack([icosphere(1).vertices, [[9, 9, 9]]]), np.vstack([icosphere(1).faces, [[0, 0, 1]],
                                                                         icosphere(1).faces[:1, [1, 2, 0]]]))
    c = clean(m)
    assert c.n_faces == icosphere(1).n_faces and c.n_vertices == icosphere(1).n_vertices


@pytest.mark.parametrize("shape", ["sphere", "torus"])
def test_marching_tetrahedra_is_closed_manifold_and_accurate(shape):
    g = np.linspace(-1.6, 1.6, 56)
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    if shape == "sphere":
        field, exact, expected_genus = 1.0 - np.sqrt(X ** 2 + Y ** 2 + Z ** 2), 4 / 3 * np.pi, 0
    else:
        field = 0.35 - np.sqrt((np.sqrt(X ** 2 + Y ** 2) - 1.0) ** 2 + Z ** 2)
        exact, expected_genus = 2 * np.pi ** 2 * 1.0 * 0.35 ** 2, 1
    mesh = marching_tetrahedra(field, 0.0, [-1.6] * 3, g[1] - g[0])
    report = inspect(mesh)
    assert report.closed_manifold, report.issues
    assert report.genus == expected_genus
    assert volume(mesh) == pytest.approx(exact, rel=0.02)  # outward winding: positive volume


def test_marching_tetrahedra_on_grid_aligned_values_has_no_slivers():
    g = np.arange(-6, 7, dtype=float)  # the level set passes through grid points exactly
    X, Y, Z = np.meshgrid(g, g, g, indexing="ij")
    mesh = marching_tetrahedra(4.0 - np.maximum(np.abs(X), np.maximum(np.abs(Y), np.abs(Z))), 0.0, [-6] * 3, 1.0)
    assert inspect(mesh).closed_manifold and mesh.face_areas().min() > 0


def test_midpoint_subdivision_is_exact():
    mesh = blob(2)
    fine, parents = midpoint(mesh)
    V = mesh.n_vertices
    assert fine.n_faces == 4 * mesh.n_faces
    assert np.array_equal(fine.vertices[:V], mesh.vertices)  # originals unchanged, same indices
    assert np.allclose(fine.vertices[V:], 0.5 * (mesh.vertices[parents[:, 0]] + mesh.vertices[parents[:, 1]]))
    assert len(parents) == len(np.unique(np.sort(parents, 1), axis=0)) == 3 * mesh.n_faces // 2
    # child faces 4f..4f+3 tile parent face f: same total area, same normal direction
    child_area = fine.face_areas().reshape(-1, 4).sum(1)
    assert np.allclose(child_area, mesh.face_areas())
    assert np.all(np.einsum("ij,ij->i", fine.face_normals().reshape(-1, 4, 3)[:, 3], mesh.face_normals()) > 0.999)
    assert inspect(fine).closed_manifold and inspect(fine).euler == inspect(mesh).euler


def test_simplify_never_exceeds_its_target():
    mesh = icosphere(5)  # 20480 faces
    for target in (5000, 1234, 99):
        out = simplify(mesh, target)
        assert out.n_faces <= target
        assert out.n_faces >= 0.9 * target
        assert inspect(out).closed_manifold


def test_simplifying_a_subdivided_mesh_keeps_it_on_the_surface():
    """Midpoint subdivision makes each old face flat; simplification must not throw vertices off."""
    mesh = icosphere(3)
    budget = FaceBudget(mesh.n_faces)
    for _ in range(4):
        mesh, _ = budget.refine(mesh)
        radius = np.linalg.norm(mesh.vertices, axis=1)
        assert radius.max() < 1.0 + 1e-3 and radius.min() > 0.99
        centre = mesh.vertices[mesh.faces].mean(1)
        assert np.all(np.einsum("ij,ij->i", mesh.face_normals(), centre) > 0.9 * np.linalg.norm(centre, axis=1))


def test_face_budget_is_honoured_and_grows():
    mesh = icosphere(3)  # 1280 faces
    budget = FaceBudget(mesh.n_faces)
    assert budget.limit == 2 * 1280
    limits = []
    for _ in range(4):
        limit = budget.limit
        mesh, exact = budget.refine(mesh)
        assert mesh.n_faces <= limit and not exact
        limits.append(limit)
    assert limits == [2560, 3200, 3840, 4480]  # + half the initial count per simplification
    small = FaceBudget(1000, limit=5000)
    out, exact = small.refine(icosphere(2))  # 320 -> 1280 fits: an exact subdivision
    assert exact and out.n_faces == 1280 and small.limit == 5000
    assert small.next_target(1000) == 4000 and small.limit == 5000
    assert small.next_target(2000) == 5000 and small.limit == 5500
    fast = FaceBudget(1280, growth=1.5)  # multiplied instead
    limits = []
    for _ in range(3):
        limits.append(fast.limit)
        mesh, _ = fast.refine(mesh)
        assert mesh.n_faces <= limits[-1]
    assert limits == [2560, 3840, 5760] and FaceBudget(**fast.state()) == fast


def test_vertex_normals_and_shading_normals_follow_a_transform():
    sphere = icosphere(3)
    n = sphere.vertex_normals()
    assert np.all((n * sphere.vertices).sum(1) / np.linalg.norm(sphere.vertices, axis=1) > 0.999)  # radial
    sphere.attributes.update(nx=n[:, 0], ny=n[:, 1], nz=n[:, 2])
    m = np.diag([2.0, 1.0, 1.0, 1.0])  # stretched along x: normals follow the inverse transpose
    m[:3, 3] = [0.5, 0.0, -1.0]
    ellipsoid = sphere.transformed(m)
    expected = n * [0.5, 1.0, 1.0]
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(ellipsoid.shading_normals, expected, atol=1e-6)
    np.testing.assert_allclose(sphere.shading_normals, n, atol=1e-7)  # the original is untouched
