"""Laplacian-preconditioned steps, the non-finite guard, outlier clipping, the schedule."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from backend.optimize.convergence import Plateau, keeps_improving, level_size
from backend.optimize.steps import Adam, LaplacianSystem, VertexOptimizer, clip_outliers, finite
from backend.synth.procedural import icosphere


def test_laplacian_system_solves_and_smooths():
    mesh = icosphere(3)
    system = LaplacianSystem(mesh.faces, mesh.n_vertices, 20.0)
    b = np.random.default_rng(0).normal(size=(mesh.n_vertices, 3))
    x = system.solve(b)
    assert np.allclose(system.multiply(x), b, atol=1e-8)
    # a spike at one vertex spreads over its neighbourhood and keeps its sum (rows of L sum to 0)
    spike = np.zeros((mesh.n_vertices, 3))
    spike[0] = 1.0
    smooth = system.solve(spike)
    assert smooth[0, 0] < 0.2 and np.isclose(smooth[:, 0].sum(), 1.0) and np.sum(smooth[:, 0] > 1e-3) > 10


def test_vertex_optimizer_descends_with_steps_of_about_lr():
    mesh = icosphere(3)
    target = mesh.vertices * 1.2
    lr = 0.01
    opt = VertexOptimizer(mesh.vertices, mesh.faces, 10.0, lr)
    u0 = opt.u.copy()
    v = opt.step(2 * (mesh.vertices - target))
    assert np.abs(opt.u - u0).max() == pytest.approx(lr, rel=1e-6)  # uniform Adam: largest step = lr
    for _ in range(300):
        v = opt.step(2 * (v - target))
    assert np.abs(v - target).max() < 0.05 * np.abs(mesh.vertices - target).max()
    opt.set_vertices(mesh.vertices)
    assert np.allclose(opt.vertices, mesh.vertices)


def test_non_finite_guard():
    good = np.ones((4, 3))
    assert finite(good, np.zeros(2))
    for bad in (np.array([1.0, np.nan]), np.array([np.inf]), np.array([-np.inf, 0.0])):
        assert not finite(good, bad)


def test_clip_outliers_caps_the_top_tail_only():
    g = np.full((1000, 3), 0.01)
    g[:30] = 0.5  # a localised signal: 3 % of the vertices
    g[7] = 100.0  # one spike
    out = clip_outliers(g, 99.5)
    assert np.linalg.norm(out[7]) == pytest.approx(np.linalg.norm(g[8]))
    assert np.allclose(out[8:], g[8:]) and np.allclose(out[:7], g[:7])
    assert clip_outliers(g, 0) is g


def test_adam_moves_against_the_gradient():
    adam = Adam(lr=0.1)
    x = {"a": np.array([1.0, -1.0])}
    for _ in range(50):
        x = adam.step(x, {"a": 2 * x["a"]})
    assert np.all(np.abs(x["a"]) < 0.5)


def test_plateau_and_level_rules():
    p = Plateau(tolerance=0.01, patience=2)
    assert p.update(1.0) and p.update(0.9)
    assert not p.update(0.895)  # less than 1 % better: not an improvement
    assert not p.converged
    assert not p.update(0.95)
    assert p.converged and p.best == 0.9
    assert [level_size(k, 64, 256) for k in range(4)] == [64, 128, 256, 256]
    def record(size, loss):
        return SimpleNamespace(size=size, loss=loss)

    assert keeps_improving(None, record(64, 1.0), 0.01)
    assert keeps_improving(record(64, 1.0), record(128, 2.0), 0.01)  # new size: go on
    assert not keeps_improving(record(128, 1.0), record(128, 0.995), 0.01)
    assert keeps_improving(record(128, 1.0), record(128, 0.98), 0.01)
    assert math.isinf(Plateau().best)
