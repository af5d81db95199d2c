"""Gauss-Newton (Levenberg-Marquardt) steps on one frame's six pose parameters, from per-pixel
image Jacobians (``backend.optimize.camera_fit`` calls it after its Adam sweeps).

Why. Adam on the noisy loss gradient stalls where the pose's steep direction (a pan, seen by
every pixel) and its shallow one (an orbit against a sideways move, seen only through the
object's parallax) differ by orders of magnitude in curvature: a step small enough for the steep
one barely moves the shallow one, and the gradient's noise then dominates it. A Gauss-Newton step
solves the 6 x 6 normal equations, so each direction moves by its own curvature.

Parameters. p = (omega (3), phi (2), dolly): the pose correction of ``camera_model.delta``,
omega taken additively (axis-angle; the steps are small).

Maths. With r(p) = t(I(q(p))) - t(y) (the toned render of the mesh moved by the vertex map q
against the toned target, per pixel and channel, N of them) the data term is L = |r|^2 / N and
J = dr/dp is six forward-mode derivatives of one render (the vertex tangents dq/dp_j are those of
the closed-form map, taken by central differences in float64). The prior is the residual
e(p) = sqrt(w) (log R_delta / SIGMA_ROT, t / (d SIGMA_T)) with E = |e|^2 / 2 (``camera_fit``'s
prior, w = ``STEP_PRIOR`` times the frame's loss when the steps begin). The step solves
(H + lambda diag H) dp = -g with H = 2 J^T J / N + J_e^T J_e, g = 2 J^T r / N + J_e^T e, and
lambda = ``LAMBDA0`` = 0: the shallow direction is a mix of an orbit and a pan whose eigenvalue is
about 1e-3 of the diagonal entries, so damping in units of diag H, at any lambda above about
1e-4, shortens exactly the step that direction needs.

Noise. The residual comes from a primal render at ``RESIDUAL_SPP`` x the level's samples with one
seed, the Jacobian from another seed: a residual and a Jacobian of the same samples are
correlated, which biases J^T r (the gradient of the renders' variance). A step is kept only
when the loss at the new pose, rendered with the same seed and samples as the current one
(common random numbers: the two renders' noise cancels in the comparison), plus the prior is
lower; else the step is retried once at half its length (``BACKTRACK``).

Prior. With the mesh frozen the data term has no gauge freedom, and the sweeps' prior (weight
0.05 of the loss per sigma^2) is as stiff as the data term along the shallow direction near the
optimum (curvature about 0.03 against 0.05 rad^-2 in units of the loss), so it would hold that
direction at a fraction of its error. ``STEP_PRIOR`` = 0: the steps follow the data; the sweeps
keep their prior, which holds the common motion of the cameras between levels."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .camera_model import delta, log_rotation

RESIDUAL_SPP = 16  # the residual's and the comparison's samples, in multiples of the level's spp
LAMBDA0 = 0.0  # the damping (relative to diag H)
BACKTRACK = 0.5  # a rejected step is retried once at this fraction of its length
STEP_PRIOR = 0.0  # the prior's weight during the steps, in units of the sweeps' (camera_fit.PRIOR)
MAX_STEP = float(np.radians(0.5))  # the largest step in any pose parameter (rad, or distances)


def pose_vector(k, i: int) -> np.ndarray:
    return np.concatenate([k.omega[i], k.phi[i], [k.dolly[i]]])


def set_pose(k, i: int, p: np.ndarray) -> None:
    k.omega[i], k.phi[i], k.dolly[i] = p[:3], p[3:5], float(p[5])


def prior_residual(p: np.ndarray, focus: np.ndarray, distance: float, weight: float, sigma_rot: float,
                   sigma_t: float) -> np.ndarray:
    """e(p) (see the module): E = |e|^2 / 2 is camera_fit's pose prior."""
    r_delta, t = delta(p[:3], p[3:5], float(p[5]), focus)
    return np.sqrt(weight) * np.concatenate([log_rotation(r_delta) / sigma_rot, t / (distance * sigma_t)])


def jacobian_fd(fn, p: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d fn / d p by central differences (fn smooth and float64: the error is O(h^2))."""
    cols = [(np.asarray(fn(p + h * e)) - np.asarray(fn(p - h * e))) / (2 * h) for e in np.eye(len(p))]
    return np.stack(cols, axis=-1)


def image_jacobian(objective, view: int, vertices: np.ndarray, tangents: np.ndarray, seed: int) -> np.ndarray:
    """The toned render's derivative along each vertex tangent: (N, P) for ``tangents`` (P, V, 3),
    one forward-mode render per tangent (Mitsuba's projective integrators carry the
    silhouette's part in forward mode too)."""
    renderer = objective.renderer
    cols = []
    for tangent in tangents:
        v = mi.Float(np.asarray(vertices, np.float32).ravel())
        dr.enable_grad(v)
        objective._set_vertices(v)
        params = objective.material.attach(renderer.params)
        img = objective._tone(renderer.render_split(view, seed=seed, params=params))
        dr.set_grad(v, mi.Float(np.asarray(tangent, np.float32).ravel()))
        dr.forward_to(img)
        cols.append(np.array(dr.grad(img), np.float64).ravel())
    return np.stack(cols, axis=1)


def residual(objective, view: int, vertices: np.ndarray, seed: int, spp: int) -> np.ndarray:
    """t(render) - t(target) per pixel and channel, flattened (no gradients)."""
    objective._set_vertices(mi.Float(np.asarray(vertices, np.float32).ravel()))
    with dr.suspend_grad():
        img = objective._tone_np(np.array(objective.renderer.render(view, seed=seed, spp=spp)))
    return (img - objective.targets_np[view]).ravel().astype(np.float64)


def lm_step(jac: np.ndarray, res: np.ndarray, e: np.ndarray, jac_e: np.ndarray, lam: float) -> np.ndarray:
    """The damped Gauss-Newton step dp (see the module), each component held to ``MAX_STEP``."""
    n = len(res)
    h = 2.0 * jac.T @ jac / n + jac_e.T @ jac_e
    g = 2.0 * jac.T @ res / n + jac_e.T @ e
    a = h + lam * np.diag(np.maximum(np.diag(h), 1e-30))
    try:
        dp = -np.linalg.solve(a, g)
    except np.linalg.LinAlgError:
        return np.zeros_like(g)
    biggest = float(np.max(np.abs(dp))) if dp.size else 0.0
    return dp * min(1.0, MAX_STEP / biggest) if biggest > 0 and np.isfinite(biggest) else np.zeros_like(g)
