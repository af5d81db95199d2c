"""Geometry metrics against analytically known values."""

import math

import numpy as np
import pytest

from backend.geometry.mesh import Mesh
from backend.metrics import geometry as geo
from tests.metrics.metric_meshes import blob, similarity, square


def test_sampling_is_deterministic_area_weighted_and_on_the_surface():
    # two triangles of area 1 and 3, in different planes
    mesh = Mesh([[0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 0, 1], [0, 3, 1], [2, 0, 1]], [[0, 1, 2], [3, 4, 5]])
    n = 20000
    s = geo.sample_surface(mesh, n, seed=3)
    again = geo.sample_surface(mesh, n, seed=3)
    other = geo.sample_surface(mesh, n, seed=4)
    assert np.array_equal(s.points, again.points)
    assert not np.array_equal(s.points, other.points)
    share = np.mean(s.faces == 1)
    assert abs(share - 0.75) < 5 * math.sqrt(0.75 * 0.25 / n)
    assert np.all(s.barycentric >= 0) and np.allclose(s.barycentric.sum(1), 1)
    assert np.allclose(s.points[:, 2], s.faces)  # each point lies in its face's plane
    # uniform inside a triangle: the sample mean is the centroid
    on_second = s.points[s.faces == 1]
    assert np.allclose(on_second.mean(0), mesh.vertices[3:].mean(0), atol=0.03)


def test_zero_area_mesh_is_rejected():
    with pytest.raises(ValueError):
        geo.sample_surface(Mesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]]), 10)


def test_normalisation_maps_truth_bbox_to_unit_longest_side():
    mesh = Mesh([[1, 2, 3], [5, 2, 3], [1, 4, 4]], [[0, 1, 2]])
    pts = geo.apply(geo.normalisation(mesh), mesh.vertices)
    lo, hi = pts.min(0), pts.max(0)
    assert np.allclose(0.5 * (lo + hi), 0) and np.isclose((hi - lo).max(), 1)


def test_identical_meshes_score_perfectly():
    m = geo.geometry_metrics(blob(), blob(), samples=5000)
    assert m["chamfer_l1"] == 0
    assert m["f1@0.01"] == 100 and m["f1@0.005"] == 100


@pytest.mark.parametrize("d", [0.003, 0.007, 0.02])
def test_parallel_squares_same_triangulation(d):
    # same seed and triangulation: every predicted sample sits exactly d above its twin,
    # which is its nearest truth sample, so Chamfer = d and F1 is 100 or 0 by tau.
    m = geo.geometry_metrics(square(z=d), square(), samples=5000)
    assert m["chamfer_l1"] == pytest.approx(d, abs=1e-12)
    for tau in geo.DEFAULT_TAUS:
        assert m[f"f1@{tau:g}"] == (100.0 if d < tau else 0.0)


@pytest.mark.parametrize("d", [0.0, 0.004, 0.008])
def test_offset_square_against_another_triangulation(d):
    # The truth is the unit square; the prediction a larger square (margin > tau) with another
    # triangulation, d above it. Every truth point is exactly d from the prediction's surface;
    # a predicted point is within tau of the truth when it lies over the unit square grown by
    # rho = sqrt(tau^2 - d^2), an area of 1 + 4 rho + pi rho^2 out of 1.44.
    n = 20000
    m = geo.geometry_metrics(square(-0.1, 1.1, z=d, fan=True), square(), samples=n, seed=1)
    assert m["truth_extent"] == 1.0
    assert m["completeness"] == pytest.approx(d, abs=1e-6)  # float32 vertices
    for tau in geo.DEFAULT_TAUS:
        assert m[f"recall@{tau:g}"] == (100.0 if d < tau else 0.0)
        rho = math.sqrt(max(tau * tau - d * d, 0))
        share = (1 + 4 * rho + math.pi * rho * rho) / 1.44 if d < tau else 0.0
        assert m[f"precision@{tau:g}"] == pytest.approx(100 * share, abs=100 * 4 * math.sqrt(0.25 / n))


def test_a_surface_scores_zero_against_its_own_retriangulation():
    m = geo.geometry_metrics(square(fan=True), square(), samples=5000, seed=2)
    assert m["chamfer_l1"] < 1e-6 and m["f1@0.005"] == 100


def test_point_triangle_distance_in_every_region():
    a, b, c = np.array([[0.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]])
    cases = {(0.2, 0.2, 0.5): 0.5,  # over the interior: to the plane
             (-1.0, -1.0, 0.0): math.sqrt(2),  # beyond a vertex
             (0.5, -2.0, 1.0): math.sqrt(5),  # beyond an edge
             (1.0, 1.0, 0.0): math.sqrt(0.5)}  # beyond the hypotenuse
    p = np.array(list(cases), float)
    d = geo.point_triangle_distance(p, *(np.repeat(x, len(p), 0) for x in (a, b, c)))
    assert np.allclose(d, list(cases.values()), atol=1e-12)
    # against brute force: the nearest of dense points on random triangles
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(3, 3))
    q = rng.normal(size=(100, 3))
    dense = geo.sample_surface(Mesh(tri, [[0, 1, 2]]), 40_000, seed=0).points
    brute = np.min(np.linalg.norm(q[:, None, :] - dense[None, :, :], axis=2), axis=1)
    exact = geo.point_triangle_distance(q, *(np.repeat(tri[i:i + 1], len(q), 0) for i in range(3)))
    assert np.all(exact <= brute + 1e-6) and np.allclose(exact, brute, atol=0.015)


def test_sampling_noise_floor_of_one_surface():
    # Two independent samplings of one square: mean nearest distance ~ 0.5 / sqrt(density)
    n = 20000
    a = geo.sample_surface(square(), n, seed=0).points
    b = geo.sample_surface(square(), n, seed=1).points
    m = geo.distance_metrics(a, b)
    assert m["chamfer_l1"] == pytest.approx(0.5 / math.sqrt(n), rel=0.03)  # edges add ~1 %


def test_metrics_are_invariant_to_common_scale_and_translation():
    # (not to rotation: the normalisation uses the truth's axis-aligned bounding box)
    pred, truth = blob(), blob().transformed(similarity(0, [0, 0, 1], 1.02, [0.01, 0, 0]))
    base = geo.geometry_metrics(pred, truth, samples=4000)
    t = similarity(0, [0, 0, 1], 7.5, [3, -2, 1])
    moved = geo.geometry_metrics(pred.transformed(t), truth.transformed(t), samples=4000)
    for key in ("chamfer_l1", "f1@0.01", "f1@0.005"):
        assert moved[key] == pytest.approx(base[key], rel=1e-9, abs=1e-9)
    assert moved["truth_extent"] == pytest.approx(7.5 * base["truth_extent"])


def test_align_similarity_recovers_exact_transform():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(50, 3))
    t = similarity(70, [1, -1, 2], 2.5, [1, 2, 3])
    m = geo.align_similarity(src, geo.apply(t, src))
    assert np.allclose(m, t, atol=1e-10)
    rigid = geo.align_similarity(src, geo.apply(similarity(70, [1, -1, 2], 1.0, [1, 2, 3]), src),
                                 with_scale=False)
    assert np.isclose(np.linalg.det(rigid[:3, :3]), 1)
    mirrored = geo.align_similarity(src, src * [-1, 1, 1])  # best proper rotation, never a reflection
    assert np.linalg.det(mirrored[:3, :3]) > 0


def test_icp_undoes_a_similarity():
    truth = blob()
    t = similarity(40, [1, 2, 0.5], 1.4, [0.3, -0.2, 0.5])
    source = truth.transformed(t)
    m = geo.align_by_icp(source, truth, samples=5000)
    assert np.allclose(m @ t, np.eye(4), atol=1e-3)
    aligned = geo.geometry_metrics(source.transformed(m), truth, samples=5000)
    assert aligned["chamfer_l1"] < 1e-3 and aligned["f1@0.005"] > 99


def test_corresponding_albedo_at_the_same_points():
    # albedo linear in position, so interpolation is exact and each predicted value tells
    # the point it came from: that point must be a close neighbour of the truth sample
    truth = blob()
    truth.vertex_colors = (0.5 + 0.2 * truth.vertices).astype(np.float32)
    pa, ga = geo.corresponding_albedo(truth, truth, samples=2000)
    assert np.array_equal(pa, ga)  # a mesh against itself: exact twins
    pred = blob(30, 60)  # another tessellation of the same shape
    pred.vertex_colors = (0.6 + 0.2 * pred.vertices).astype(np.float32)
    pa, ga = geo.corresponding_albedo(pred, truth, samples=2000)
    assert pa.shape == ga.shape == (2000, 3)
    gt_points = geo.sample_surface(truth, 2000).points
    assert np.allclose(ga, 0.5 + 0.2 * gt_points, atol=1e-6)
    gaps = np.linalg.norm((pa - 0.6) / 0.2 - gt_points, axis=1)
    assert gaps.max() < 0.05
    assert abs(np.mean(pa - ga) - 0.1) < 2e-3
    with pytest.raises(ValueError):
        geo.corresponding_albedo(blob(), truth, samples=10)


def test_icp_ignores_a_stray_surface():
    # a small floater above the object (2 % of its area) is dropped by the trimming
    truth = blob()
    stray = blob(8, 16).transformed(similarity(0, [0, 0, 1], 0.15, [0, 0, 1.0]))
    merged = Mesh(np.vstack([truth.vertices, stray.vertices]),
                  np.vstack([truth.faces, stray.faces + truth.n_vertices]))
    t = similarity(30, [1, 2, 0.5], 1.4, [0.3, -0.2, 0.5])
    m = geo.align_by_icp(merged.transformed(t), truth, samples=5000)
    assert np.allclose(m @ t, np.eye(4), atol=1e-3)
