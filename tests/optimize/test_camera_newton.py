"""Gauss-Newton steps on the camera poses (backend/optimize/camera_newton.py): the damped step,
the prior's residual form, the forward-mode image Jacobian against differences of real renders,
and recovery with the steps on (real renders)."""

from __future__ import annotations

import numpy as np

from backend.bench.cameras import FixedMaterial, recovery
from backend.capture.load import load_capture
from backend.geometry.mesh import load_mesh
from backend.optimize import camera_fit as cf, camera_model as cm, camera_newton as gn
from backend.optimize.objective import Objective
from backend.optimize.views import ViewSet
from backend.render.scene import RenderSettings


def test_an_undamped_step_solves_the_linear_least_squares_problem_and_is_held_to_the_limit():
    rng = np.random.default_rng(0)
    jac, truth = rng.normal(size=(400, 6)), rng.normal(size=6) * 1e-3
    res = -jac @ truth  # r(p + dp) = r + J dp vanishes at dp = truth
    e, jac_e = np.zeros(6), np.zeros((6, 6))
    np.testing.assert_allclose(gn.lm_step(jac, res, e, jac_e, 0.0), truth, rtol=1e-9, atol=1e-12)
    far = gn.lm_step(jac, -jac @ (truth * 1e3), e, jac_e, 0.0)
    assert np.isclose(np.max(np.abs(far)), gn.MAX_STEP)
    np.testing.assert_allclose(far / np.max(np.abs(far)), truth / np.max(np.abs(truth)), rtol=1e-9)


def test_the_prior_residual_is_the_sweeps_prior():
    rng = np.random.default_rng(1)
    focus, distance, w = np.array([0.1, -0.2, -3.0]), 3.0, 0.37
    p = rng.normal(size=6) * 0.01
    r_delta, t = cm.delta(p[:3], p[3:5], float(p[5]), focus)
    energy = 0.5 * w * (np.sum(cm.log_rotation(r_delta) ** 2) / cf.SIGMA_ROT**2
                        + np.sum(t**2) / (distance * cf.SIGMA_T) ** 2)
    e = gn.prior_residual(p, focus, distance, w, cf.SIGMA_ROT, cf.SIGMA_T)
    assert np.isclose(0.5 * e @ e, energy, rtol=1e-12)


def test_the_forward_mode_image_jacobian_matches_differences_of_renders(tiny_capture):
    capture = load_capture(tiny_capture)
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    views = ViewSet(capture, 32).at(32)[:1]
    settings = RenderSettings(spp=16, max_depth=2, integrator="direct_projective", sppc=16, sppp=16)
    objective = Objective(mesh, FixedMaterial(mesh), views, settings, capture.environment)
    camera = views[0].camera
    points = np.asarray(mesh.vertices, np.float64)
    lo, hi = mesh.bounds()
    focus = camera.camera_to_world[:3, :3].T @ (0.5 * (lo + hi) - camera.centre)

    def moved(p):
        m, b, _ = cm.vertex_map(camera, *cm.delta(p[:3], p[3:5], float(p[5]), focus), 0.0, np.zeros(2))
        return points @ m.T + b

    zero, h = np.zeros(6), 1.0 / camera.fx  # a pan of about a pixel
    tangents = np.moveaxis(gn.jacobian_fd(moved, zero), -1, 0)[[0, 1]]  # tilt and pan
    jac = gn.image_jacobian(objective, 0, moved(zero), tangents, seed=3)
    assert jac.shape == (32 * 32 * 3, 2) and np.all(np.isfinite(jac))
    for j, e in enumerate(np.eye(6)[[0, 1]]):
        ahead, behind = (gn.residual(objective, 0, moved(s * h * e), 5, 256) for s in (1, -1))
        diff = (ahead - behind) / (2 * h)
        cosine = float(jac[:, j] @ diff / (np.linalg.norm(jac[:, j]) * np.linalg.norm(diff)))
        assert cosine > 0.6, (j, cosine)
        assert 0.5 < np.linalg.norm(jac[:, j]) / np.linalg.norm(diff) < 2.0


def test_newton_steps_recover_perturbed_cameras_with_few_sweeps(tiny_capture):
    """Two sweeps alone leave most of a 1-degree error; the steps after them bring the
    reprojection to a fraction of a pixel."""
    out = recovery(tiny_capture, size=48, sweeps=2, rounds=1, intrinsics=False, newton=3)
    before, after = out["before"], out["after"]
    assert out["history"][-1]["newton"] == 3 and not out["history"][-1]["diverged"]
    assert after["reprojection_px"] < 0.3 * before["reprojection_px"], out
    assert after["rotation_deg"]["mean"] < 0.8 * before["rotation_deg"]["mean"], out


def test_the_undamped_step_moves_the_shallow_direction_that_diagonal_damping_holds():
    """A pan against an orbit: two columns nearly alike, so the smaller eigenvalue of J^T J is
    about 1e-4 of its diagonal. The step at ``LAMBDA0`` recovers an error along that direction;
    damping of 1e-3 diag H (the former start) recovers a small part of it."""
    rng = np.random.default_rng(2)
    base = rng.normal(size=(2000, 6))
    base[:, 3] = base[:, 1] + 0.02 * rng.normal(size=2000)  # the orbit sees the pan plus a parallax
    shallow = np.array([0.0, 1.0, 0.0, -1.0, 0.0, 0.0]) / np.sqrt(2.0)
    truth = 2e-3 * shallow
    res = -base @ truth
    e, jac_e = np.zeros(6), np.zeros((6, 6))
    undamped = gn.lm_step(base, res, e, jac_e, gn.LAMBDA0)
    damped = gn.lm_step(base, res, e, jac_e, 1e-3)
    assert abs(undamped @ shallow / (truth @ shallow) - 1.0) < 1e-6
    assert damped @ shallow / (truth @ shallow) < 0.5
