"""Mesh colors with a resolution per face: shared samples, the Dr.Jit lookup against numpy,
transfer between resolutions, save/load and the display mesh."""

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.material.meshcolors import MeshColorLayout, local_samples  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from tests.material.helpers import lookup_numpy, lumpy, random_points  # noqa: E402


def mixed(mesh, seed=0, lo=1, hi=7):
    return np.random.default_rng(seed).integers(lo, hi, mesh.n_faces)


def textured(mesh, resolution, seed=0):
    rng = np.random.default_rng(seed)
    m = MeshColorMaterial(mesh, resolution)
    for name in m.CHANNELS:
        m.make_spatial(name)
        m.set_values(name, rng.uniform(0.05, 0.95, (m.layout.n_samples, m.CHANNELS[name][0])))
    return m


def test_mixed_layout_shares_vertex_samples_and_equal_resolution_edges():
    mesh = lumpy(1)
    res = mixed(mesh)
    layout = MeshColorLayout(mesh.faces, mesh.n_vertices, res)
    assert not layout.uniform and layout.resolution == res.max()
    assert np.array_equal(np.diff(layout.offsets), (res + 1) * (res + 2) // 2)
    refs = np.bincount(layout.entries, minlength=layout.n_samples)
    assert np.all(refs > 0)
    V = mesh.n_vertices
    assert np.array_equal(refs[:V], np.bincount(mesh.faces.ravel(), minlength=V))  # vertices: every face
    # each entry lies where its shared sample lies, so faces that share a sample agree on its point
    bary = layout.entry_barycentrics()
    tri = mesh.vertices[mesh.faces[layout.entry_face]]
    pts = (1 - bary.sum(1, keepdims=True)) * tri[:, 0] + bary[:, :1] * tri[:, 1] + bary[:, 1:] * tri[:, 2]
    assert np.abs(pts - layout.sample_positions(mesh.vertices)[layout.entries]).max() < 1e-12
    # an edge sample is shared exactly when the edge's two faces have the same r
    pairs = np.sort(np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]]), 1)
    _, edge = np.unique(pairs, axis=0, return_inverse=True)
    owners = np.argsort(edge.ravel(), kind="stable") % mesh.n_faces
    a, b = owners[0::2], owners[1::2]
    same = res[a] == res[b]
    expected_edge_samples = int(np.where(same, res[a] - 1, res[a] + res[b] - 2).sum())
    interior = int(((res - 1) * (res - 2) // 2).sum())
    assert layout.n_samples == V + expected_edge_samples + interior


def test_uniform_resolution_array_is_the_uniform_layout():
    mesh = lumpy(1)
    a = MeshColorLayout(mesh.faces, mesh.n_vertices, 3)
    b = MeshColorLayout(mesh.faces, mesh.n_vertices, np.full(mesh.n_faces, 3))
    assert b.uniform and np.array_equal(a.table, b.table) and a.n_samples == b.n_samples


def test_mixed_layout_refuses_resolution_zero():
    mesh = lumpy(0)
    res = mixed(mesh)
    res[0] = 0
    with pytest.raises(ValueError):
        MeshColorLayout(mesh.faces, mesh.n_vertices, res)


def test_mixed_lookup_hits_samples_and_matches_numpy():
    mesh = lumpy(1)
    m = textured(mesh, mixed(mesh, 1))
    layout = m.layout
    bary = layout.entry_barycentrics()
    got = lookup_numpy(m, layout.entry_face, bary[:, 0], bary[:, 1])
    rng = np.random.default_rng(2)
    face, b = random_points(mesh.n_faces, 5000, rng)
    inside = lookup_numpy(m, face, b[:, 1], b[:, 2])
    expected = m.evaluate(face, b[:, 1], b[:, 2])
    for name in m.CHANNELS:
        assert np.abs(got[name] - m.values(name)[layout.entries]).max() < 2e-6
        assert np.abs(inside[name] - expected[name]).max() < 2e-6


def test_values_round_trip_through_resolution_changes():
    """Uniform r -> per-face multiples of r -> back: exact (each new grid refines the old)."""
    mesh = lumpy(1)
    m = textured(mesh, 2, seed=3)
    before = {n: m.values(n).copy() for n in m.CHANNELS}
    rng = np.random.default_rng(4)
    face, b = random_points(mesh.n_faces, 3000, rng)
    at = m.evaluate(face, b[:, 1], b[:, 2])
    m.set_resolution(2 * rng.integers(1, 4, mesh.n_faces))  # 2, 4 or 6 per face
    assert not m.layout.uniform
    fine = m.evaluate(face, b[:, 1], b[:, 2])
    m.set_resolution(2)
    for name in m.CHANNELS:
        assert np.abs(fine[name] - at[name]).max() < 1e-5
        assert np.abs(m.values(name) - before[name]).max() < 1e-5


def test_mixed_material_saves_loads_and_displays(tmp_path):
    mesh = lumpy(1)
    res = mixed(mesh, 5, 1, 5)
    m = textured(mesh, res, seed=6)
    m.save(tmp_path / "material.npz")
    back = MeshColorMaterial.load(tmp_path / "material.npz")
    assert np.array_equal(back.resolutions, res)
    for name in m.CHANNELS:
        assert np.abs(back.values(name) - m.values(name)).max() < 1e-5
    shown = m.display(mesh)
    assert shown.n_faces == int((res ** 2).sum())
    # every display vertex sits on a sample and carries its albedo (unshared edge samples of
    # faces of unequal r can share a point, each with its own value)
    pos = m.layout.sample_positions(mesh.vertices)
    vals = m.values("albedo")
    at = ((shown.vertices[:, None] - pos[None]) ** 2).sum(-1) < 1e-18
    assert np.all(at.any(1))
    err = np.where(at, np.abs(shown.vertex_colors[:, None] - vals[None]).max(-1), np.inf).min(1)
    assert err.max() < 1e-5
    assert m.summary()["resolutions"]["max"] == res.max()


def test_local_samples_count():
    assert len(local_samples(5)) == 21
