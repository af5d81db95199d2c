"""Geometry metrics against analytically known values."""

import math

import numpy as np
import pytest
from scipy.special import erfcx

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


def expected_nn_distance(d, density):
    """E[sqrt(d^2 + r^2)] with r the nearest-neighbour distance in a planar Poisson process.

    P(r > x) = exp(-density pi x^2), so E = d + int_d^inf exp(-a (s^2 - d^2)) ds, a = density pi."""
    a = density * math.pi
    return d + 0.5 * math.sqrt(math.pi / a) * erfcx(d * math.sqrt(a))


@pytest.mark.parametrize("d", [0.0, 0.004, 0.008])
def test_offset_square_against_independent_samples(d):
    # The truth is the unit square; the prediction a larger square (margin > tau, so no
    # edge effects for truth points) with another triangulation, d above it. Truth points
    # see a uniform sample of density n / 1.2^2 over the plane z = d, so completeness and
    # recall follow from the nearest-neighbour law of a Poisson process.
    n = 20000
    m = geo.geometry_metrics(square(-0.1, 1.1, z=d, fan=True), square(), samples=n, seed=1)
    density = n / 1.2 ** 2
    assert m["truth_extent"] == 1.0
    assert m["completeness"] == pytest.approx(expected_nn_distance(d, density), rel=0.02)
    for tau in geo.DEFAULT_TAUS:
        recall = 100 * (1 - math.exp(-density * math.pi * (tau * tau - d * d))) if d < tau else 0.0
        assert m[f"recall@{tau:g}"] == pytest.approx(recall, abs=1.0)
    # a predicted point is within tau of the truth only if it lies over the unit square
    # grown by rho = sqrt(tau^2 - d^2), an area of 1 + 4 rho + pi rho^2 out of 1.44
    for tau in geo.DEFAULT_TAUS:
        rho = math.sqrt(max(tau * tau - d * d, 0))
        bound = 100 * (1 + 4 * rho + math.pi * rho * rho) / 1.44 if d < tau else 0.0
        assert m[f"precision@{tau:g}"] <= bound + 100 * 3 * math.sqrt(0.25 / n)


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
