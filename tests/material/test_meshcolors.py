"""Mesh colors: index formula, shared layout, lookup, exact gradients, seams, subdivision transfer."""

import numpy as np
import pytest

from backend import variant

variant.choose()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from backend.material.meshcolors import (MeshColorLayout, local_index, local_samples,  # noqa: E402
                                         local_sub_triangles, unique_edges)
from backend.material.model import MeshColorMaterial  # noqa: E402
from tests.material.helpers import (interaction, lookup_numpy, lumpy, midpoint_subdivide,  # noqa: E402
                                    random_points)

RESOLUTIONS = [0, 1, 2, 3, 8]


def textured(mesh, r, seed=0):
    """A material with every channel as mesh colors holding random values."""
    rng = np.random.default_rng(seed)
    m = MeshColorMaterial(mesh, r)
    for name in m.CHANNELS:
        m.make_spatial(name)
        width = m.CHANNELS[name][0]
        m.set_values(name, rng.uniform(0.05, 0.95, (m.layout.n_samples, width)))
    return m


@pytest.mark.parametrize("r", range(9))
def test_local_index_is_the_papers_formula(r):
    ij = local_samples(r)
    K = (r + 1) * (r + 2) // 2
    assert len(ij) == K
    # k = i (2r - i + 3) / 2 + j enumerates the samples row by row without gaps
    assert np.array_equal(local_index(ij[:, 0], ij[:, 1], r), np.arange(K))
    # the paper's global index t K + k addresses the per-face table in row-major order
    mesh = lumpy(0)
    layout = MeshColorLayout(mesh.faces, mesh.n_vertices, r)
    t, k = 7, K - 1
    i, j = ij[k]
    paper_k = (t * (r + 1) * (r + 2) + i * (2 * r - i + 3)) // 2 + j
    assert layout.table.ravel()[paper_k] == layout.table[t, k]


@pytest.mark.parametrize("r", RESOLUTIONS)
def test_shared_layout(r):
    mesh = lumpy(1)
    layout = MeshColorLayout(mesh.faces, mesh.n_vertices, r)
    V, F = mesh.n_vertices, mesh.n_faces
    E = len(unique_edges(mesh.faces)[0])
    expected = F if r == 0 else V + E * (r - 1) + F * (r - 1) * (r - 2) // 2
    assert layout.n_samples == expected
    refs = np.bincount(layout.table.ravel(), minlength=layout.n_samples)
    assert np.all(refs > 0)
    if r >= 1:
        valence = np.bincount(mesh.faces.ravel(), minlength=V)
        assert np.array_equal(refs[:V], valence)  # vertex samples: every incident face
        assert np.all(refs[V:V + E * (r - 1)] == 2)  # edge samples: the edge's two faces
        assert np.all(refs[V + E * (r - 1):] == 1)  # interior samples: one face
    # every face that references a shared sample places it at the same point
    bary = layout.local_barycentrics()
    tri = mesh.vertices[mesh.faces]
    pts = (np.einsum("k,fd->fkd", 1 - bary.sum(1), tri[:, 0]) + np.einsum("k,fd->fkd", bary[:, 0], tri[:, 1])
           + np.einsum("k,fd->fkd", bary[:, 1], tri[:, 2]))
    pos = layout.sample_positions(mesh.vertices)
    assert np.abs(pts - pos[layout.table]).max() < 1e-12


@pytest.mark.parametrize("r", RESOLUTIONS)
def test_lookup_hits_samples_and_is_linear_in_sub_triangles(r):
    mesh = lumpy(1)
    m = textured(mesh, r)
    F = mesh.n_faces
    local = m.layout.local_barycentrics()
    face = np.repeat(np.arange(F), len(local))
    got = lookup_numpy(m, face, np.tile(local[:, 0], F), np.tile(local[:, 1], F))
    if r == 0:  # one value per face, anywhere on the face
        rng = np.random.default_rng(1)
        b = rng.dirichlet([1, 1, 1], F)
        got = lookup_numpy(m, np.arange(F), b[:, 1], b[:, 2])
    for name in m.CHANNELS:
        assert np.abs(got[name] - m.values(name)[m.layout.table.ravel()]).max() < 2e-6
    if r == 0:
        return
    # inside each sub-triangle the lookup is the barycentric blend of its three samples
    rng = np.random.default_rng(2)
    subs = local_sub_triangles(r)
    n = 4000
    face, which = rng.integers(0, F, n), rng.integers(0, len(subs), n)
    w = rng.dirichlet([1, 1, 1], n)
    corner_bary = local[subs[which]]  # (n, 3, 2)
    b = np.einsum("nk,nkd->nd", w, corner_bary)
    got = lookup_numpy(m, face, b[:, 0], b[:, 1])
    samples = m.layout.table[face[:, None], subs[which]]
    for name in m.CHANNELS:
        expected = np.einsum("nk,nkc->nc", w, m.values(name)[samples])
        assert np.abs(got[name] - expected).max() < 2e-6


@pytest.mark.parametrize("r", RESOLUTIONS)
def test_gradient_matches_central_differences(r):
    mesh = lumpy(0)
    m = textured(mesh, r, seed=3)
    rng = np.random.default_rng(4)
    face, b = random_points(mesh.n_faces, 3000, rng)
    si = interaction(face, b[:, 1], b[:, 2])
    coef = mi.Float(rng.uniform(0.5, 1.5, len(face)).astype(np.float32))

    def terms():  # a smooth, non-linear function of all three channels, per point
        albedo, spec, rough = m.field.lookup(si, mi.Bool(True))
        return coef * (dr.square(albedo.x) + dr.sin(3 * albedo.y) * albedo.z + spec * rough + dr.square(rough))

    latents = m.parameters()
    base = {n: np.array(v, np.float64) for n, v in latents.items()}
    for v in latents.values():
        dr.enable_grad(v)
    dr.backward(dr.sum(terms()))
    for name, z0 in base.items():
        grad = np.array(dr.grad(latents[name]), np.float64)
        dr.disable_grad(latents[name])
        fd = np.zeros_like(z0)
        h = 1e-2
        for k in rng.choice(len(z0), min(len(z0), 60), replace=False):
            vals = []
            for s in (h, -h):
                z = z0.copy()
                z[k] += s
                m.load_parameters({name: mi.Float(z.astype(np.float32))})
                with dr.suspend_grad():
                    vals.append(np.array(terms(), np.float64).sum())  # unchanged terms cancel exactly
            fd[k] = (vals[0] - vals[1]) / (2 * h)
        m.load_parameters({name: mi.Float(z0.astype(np.float32))})
        checked = fd != 0
        assert checked.sum() > 0
        rel = np.linalg.norm(grad[checked] - fd[checked]) / np.linalg.norm(fd[checked])
        assert rel < 0.01, f"{name}: relative error {rel:.4f}"


@pytest.mark.parametrize("r", [1, 2, 3, 8])
def test_values_agree_along_shared_edges(r):
    mesh = lumpy(1)
    m = textured(mesh, r, seed=5)
    edges, face_edges = unique_edges(mesh.faces)
    rng = np.random.default_rng(6)
    # for each edge, the two faces and the edge's corner slots in each face
    owners = [[] for _ in range(len(edges))]
    for f in range(mesh.n_faces):
        for slot in range(3):
            owners[face_edges[f, slot]].append((f, slot))
    corner_bary = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])  # (b1, b2) of v0, v1, v2
    fa, fb, pa, pb = [], [], [], []
    for e, ((f1, s1), (f2, s2)) in enumerate(owners):
        for t in rng.uniform(0, 1, 8):
            a, b = edges[e]
            p = []
            for f, s in ((f1, s1), (f2, s2)):
                ia = int(np.flatnonzero(mesh.faces[f] == a)[0])
                ib = int(np.flatnonzero(mesh.faces[f] == b)[0])
                p.append((1 - t) * corner_bary[ia] + t * corner_bary[ib])
            fa.append(f1), fb.append(f2), pa.append(p[0]), pb.append(p[1])
    pa, pb = np.array(pa), np.array(pb)
    va = lookup_numpy(m, np.array(fa), pa[:, 0], pa[:, 1])
    vb = lookup_numpy(m, np.array(fb), pb[:, 0], pb[:, 1])
    for name in m.CHANNELS:
        assert np.abs(va[name] - vb[name]).max() < 2e-6


@pytest.mark.parametrize("r", RESOLUTIONS)
def test_midpoint_subdivision_transfer_is_exact(r):
    mesh = lumpy(1)
    m = textured(mesh, r, seed=7)
    new, parent, corner_bary = midpoint_subdivide(mesh, seed=r)
    rng = np.random.default_rng(8)
    face, w = random_points(new.n_faces, 5000, rng)
    # the same surface points, expressed on the old mesh
    old_bary = np.einsum("nk,nkj->nj", w, corner_bary[face])
    before = lookup_numpy(m, parent[face], old_bary[:, 1], old_bary[:, 2])
    m.on_subdivide(mesh, new)
    assert m.n_faces == new.n_faces
    assert m.resolution == (r // 2 if r >= 2 and r % 2 == 0 else r)
    after = lookup_numpy(m, face, w[:, 1], w[:, 2])
    for name in m.CHANNELS:
        assert np.abs(after[name] - before[name]).max() < 1e-5, name


def test_resolution_outside_range_is_refused():
    mesh = lumpy(0)
    with pytest.raises(ValueError):
        MeshColorLayout(mesh.faces, mesh.n_vertices, -1)
    with pytest.raises(ValueError):
        MeshColorLayout(mesh.faces, mesh.n_vertices, 33)


@pytest.mark.parametrize("r", [2, 3])
def test_render_gradient_matches_central_differences(r):
    """Through a path-traced render (PRB, direct light, point lights): the image is linear in
    the albedo and the differential pass replays the primal samples of seed 2."""
    from backend.render.scene import RenderSettings, SceneRenderer
    from backend.synth import layout

    mesh = lumpy(1)
    m = MeshColorMaterial(mesh, r)
    m.make_spatial("albedo")
    rng = np.random.default_rng(r)
    m.set_values("albedo", rng.uniform(0.2, 0.8, (m.layout.n_samples, 3)))
    m.set_values("specular", 0.02)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(1), np.zeros(3), 1.2, 24)
    renderer = SceneRenderer(mesh, m.field, cams, [layout.paper_lights(c, 3.0) for c in cams], None,
                             RenderSettings(spp=32, max_depth=2, integrator="prb"))
    renderer.render_numpy(0)  # sets view 0's lights
    weight = rng.uniform(0, 1, (24, 24, 3))
    latent = m.parameters()["albedo"]
    z0 = np.array(latent, np.float64)
    params = m.attach(renderer.params)
    dr.enable_grad(latent)
    img = mi.render(renderer.scene, params, sensor=renderer.sensors[0], seed=1, seed_grad=2, spp=32)
    dr.backward(dr.sum(mi.TensorXf(weight.astype(np.float32)) * img))
    grad = np.array(dr.grad(latent), np.float64)
    dr.disable_grad(latent)

    def loss(z):
        m.load_parameters({"albedo": mi.Float(z.astype(np.float32))})
        with dr.suspend_grad():
            image = mi.render(renderer.scene, params, sensor=renderer.sensors[0], seed=2, spp=32)
        return float((weight * np.array(image, np.float64)).sum())

    top = np.argsort(-np.abs(grad))[:8]
    fd = []
    for k in top:
        step = np.zeros_like(z0)
        step[k] = 0.05
        fd.append((loss(z0 + step) - loss(z0 - step)) / 0.1)
    fd = np.array(fd)
    assert np.abs(grad[top]).min() > 0
    assert np.linalg.norm(grad[top] - fd) / np.linalg.norm(fd) < 0.01
