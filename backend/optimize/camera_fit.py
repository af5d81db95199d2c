"""Camera refinement (``--refine-cameras``): each frame's pose (6-DoF) and the shared intrinsics
(focal length, principal point) refined by the renders the fit already makes, with a quadratic
prior towards the cameras the run started from (``CameraFit``). Longer than 400 lines: the
sweeps, the damped pose steps' driver and the per-frame revert share one fit's state.

Parameters. Frame i's camera is C_i' = C_i Delta_i (camera-to-world, Blender camera axes), with
Delta_i = [R_delta | t] a small rigid motion in the camera's own frame (``camera_model.delta``):
a pan/tilt/roll omega_i (axis-angle about the camera centre, radians) and a dolly towards the
object's centre (in camera distances: 0.01 is 1 %), then an orbit phi_i about the object's centre
(about the camera's x and y axes): R_delta = R(phi) R(omega), t = R(phi) (dolly - 1) o + o, o the
object's centre in the camera's frame. A pan and a sideways move shift the image almost alike,
an orbit changes only the parallax; apart, Adam's per-coordinate steps see the steep and the
shallow direction each at its own scale. omega is updated on the tangent space
(R <- R exp([eps]x)). The intrinsics are shared by every frame: a log focal scale sigma
(f' = e^sigma f) and a principal point offset (a_x, a_y) = (dc_x / f_x, dc_y / f_y),
dimensionless so one value holds at every image size.

Gradient through the vertices. The projective integrators take perspective sensors whose
transforms are not differentiated, so the correction is applied to the object instead: with
y = R_delta^T (C^-1 p - t) (p in the corrected camera's frame) and the intrinsic map
B = [[s, 0, -a_x], [0, s, a_y], [0, 0, 1]] (s = e^sigma; Blender axes, z towards the camera),
the vertex q = C B y seen by the starting camera C projects exactly where p projects through
the corrected camera and intrinsics (a pinhole's u = f x / z + c: scaling x, y by s is the
focal change, adding a z is the principal point's). So one render of the moved vertices, one
backward pass, and dL/dq chains to (omega, phi, dolly, sigma, a) in closed form (``camera_model.chain``). Point
lights and a world-fixed environment map are moved with the object (the same map), so shading
is that of the corrected camera too; the intrinsic part also shears the normals by |s - 1| and
|a| (about 1e-2), which the shading does not see at that order.

Steps. Adam per parameter group (pan, orbit, dolly: a first step of ``STEP_PX`` / f, f the
level's focal length in pixels; focal scale and principal point likewise), one view per pose step, the
intrinsic gradients summed over a sweep of all views and applied once per sweep; the step
decays linearly to a tenth over the sweeps. Geometry and material are frozen meanwhile.

Prior. E = ``PRIOR`` L0_i / 2 (|log R_delta|^2 / SIGMA_ROT^2 + |t / d_i|^2 / SIGMA_T^2) per frame (L0_i
the frame's loss at the start of the refinement, so the weight reads in units of the data term),
and ``PRIOR`` L0 / 2 (sigma^2 / SIGMA_F^2 + |a f|^2 / SIGMA_PP^2) for the intrinsics (L0 the mean).
At weight 0.05 a 1-degree error whose loss is all misregistration is recovered to about 2.5 %.

Gauge. Moving every camera and the object by one similarity leaves the renders unchanged. The
mesh is frozen during camera steps, so there the gauge is fixed by the object; between them the
prior holds it (a common motion of all cameras and the object changes no data term and costs
prior energy, so the optimum keeps the correction's mean near zero). Figures against true
cameras are taken after a similarity alignment of the camera centres (``align_similarity``).

Divergence. A frame whose loss (fixed seed, no gradient) ends above its start, or any
non-finite value, takes back its last good correction; when every frame fails the refinement
keeps the starting cameras and says so (``report``). A non-finite pose is never written.

Intrinsics are nearly a common motion of every camera (a principal-point offset a common pan, a
focal change a common dolly), so the prior is what tells them apart; ``refine(intrinsics=False)``
holds them (docs/notes/2026-12-02-camera-refinement.md)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .. import fsio
from ..capture.model import Camera
from ..render.scene import environment_to_world
from .camera_model import (Correction, chain, corrected_camera, delta, log_rotation, pose_grads, reprojection_px,
                           rotation, vertex_map)
from . import camera_newton as gn
from .objective import Objective, seed_for
from .views import View, scaled_camera

MODES = ("auto", "on", "off")
HELP = ("refine each frame's pose and the shared focal length and principal point by the fit's own renders, "
        "alternating with the geometry levels from the second on (a prior holds them near the given cameras; "
        "RUN/cameras.json and report.json cameras_refined): 'auto' (the default) for captures made from a video "
        "or photos and imported real datasets (SfM cameras are off by about a pixel), not for rendered "
        "captures (exact cameras) nor for solves whose reprojection error is under 0.25 px at the fit's size; "
        "'on' always; 'off' never")
# capture.json provenance.source of the captures ``auto`` refines: capture-from-video's and the
# importers of real datasets (COLMAP, IDR/DTU, Middlebury, AliceVision); NeRF's transforms.json
# and rendered captures carry exact cameras
AUTO_SOURCES = ("video", "images", "colmap", "idr", "middlebury", "alicevision")
PRIOR = 0.05  # prior weight, in units of the frame's starting loss per sigma^2
SIGMA_ROT = float(np.radians(1.0))  # rad
SIGMA_T = 0.01  # fraction of the camera's distance
SIGMA_F = 0.01  # log focal scale
SIGMA_PP = 1.0  # principal point offset, pixels of the level's images
STEP_PX = 0.25  # Adam's largest first step, in pixels of the level's images
SWEEPS = 6  # sweeps over every view in one refinement
WORSE = 1.0  # a frame whose end loss exceeds its start loss x this takes its correction back
# Gauss-Newton steps go through the frames interleaved (every NEWTON_STRIDE-th first, so any
# prefix spans the orbit). Once NEWTON_PROBE frames have had them, their net gain (the
# refinement's own loss, its seed rather than the steps' samples, which the steps partly fit,
# after their steps against its start) decides: under NEWTON_GAIN on average the rest are left,
# since they would mostly take their corrections back. A capture whose cameras were already
# solved to a fraction of a pixel spends the time on geometry instead.
NEWTON_STRIDE = 8
NEWTON_PROBE = 8
NEWTON_GAIN = 0.003
MEASURABLE_PX = 0.25  # a solve's reprojection error at the fit's largest size that ``auto`` refines
FILENAME = "cameras.json"
FORMAT = "shape-from-tracing-cameras"


def enabled(mode: str, capture, max_size: int | None = None) -> bool:
    """Whether ``--refine-cameras mode`` refines ``capture``'s cameras: ``auto`` by what
    capture.json says of its source (``AUTO_SOURCES``): solved or measured cameras are off by
    about a pixel, rendered ones are exact; and not when the capture's own solve says they are
    already finer than the fit can see (``unmeasurable``, with the fit's ``max_size``)."""
    if mode not in MODES:
        raise ValueError(f"unknown camera refinement mode {mode!r}")
    if mode != "auto":
        return mode == "on"
    return (capture.provenance or {}).get("source") in AUTO_SOURCES and unmeasurable(capture, max_size) is None


def unmeasurable(capture, max_size: int | None) -> str | None:
    """Why ``auto`` leaves a solved capture's cameras alone, or None: the solve's mean
    reprojection error (capture.json ``provenance.sfm``, in the frames' pixels) scaled to the
    fit's largest images (``max_size``) is under ``MEASURABLE_PX``. A misregistration that small
    moves the renders less than their noise: the refinement's steps are taken back and it
    settles at once, after costing the time of a level."""
    sfm = (capture.provenance or {}).get("sfm") or {}
    error = sfm.get("reprojection_error_px")
    if max_size is None or error is None or not capture.frames:
        return None
    native = max(max(f.camera.width, f.camera.height) for f in capture.frames)
    scaled = float(error) * min(1.0, max_size / native)
    if not scaled < MEASURABLE_PX:
        return None
    return (f"the solve's {float(error):.2f} px reprojection error is {scaled:.2f} px at the fit's "
            f"{min(max_size, native)} px, under the {MEASURABLE_PX:g} px the renders can measure")


class _Adam:
    """Adam on one array, its step set per call (the sweeps' decay)."""

    def __init__(self, shape):
        self.m, self.v, self.t = np.zeros(shape), np.zeros(shape), 0

    def step(self, g, lr: float) -> np.ndarray:
        self.t += 1
        self.m = 0.9 * self.m + 0.1 * g
        self.v = 0.999 * self.v + 0.001 * g * g
        return -lr * (self.m / (1 - 0.9**self.t)) / (np.sqrt(self.v / (1 - 0.999**self.t)) + 1e-20)


class CameraFit:
    """The run's camera corrections against its starting cameras (the capture's, in order).

    Args:
        names: the frames' names.
        cameras: the frames' starting cameras, at the frames' own size.
        centre: the object's centre (world), for the cameras' distances.
    """

    def __init__(self, names: list[str], cameras: list[Camera], centre: np.ndarray):
        self.names = list(names)
        self.start = [dataclasses.replace(c, camera_to_world=np.asarray(c.camera_to_world, np.float64).copy())
                      for c in cameras]
        self.centre = np.asarray(centre, np.float64)
        # the object's centre in each camera's frame, and its distance
        self.focus = np.array([np.asarray(c.camera_to_world, np.float64)[:3, :3].T @ (self.centre - c.centre)
                               for c in self.start])
        self.distance = np.maximum(np.linalg.norm(self.focus, axis=1), 1e-6)
        self.correction = Correction.zero(len(self.start))
        self.refinements = 0
        self.reverted = 0  # frames a refinement took back (worse or non-finite)
        self.diverged = False  # the last refinement failed for every frame: its cameras were kept
        self.history: list[dict] = []

    # -- cameras -----------------------------------------------------------------------------------
    def camera(self, i: int, correction: Correction | None = None, like: Camera | None = None) -> Camera:
        """Frame ``i``'s corrected camera, at the size of ``like`` (default: the frame's own)."""
        k = correction or self.correction
        base = self.start[i] if like is None else scaled_camera(self.start[i], like.width, like.height)
        return corrected_camera(base, *self.pose(i, k), k.sigma, k.principal)

    def pose(self, i: int, correction: Correction | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``i``'s (R_delta, t) (``delta``)."""
        k = correction or self.correction
        return delta(k.omega[i], k.phi[i], float(k.dolly[i]), self.focus[i])

    def cameras(self) -> list[Camera]:
        return [self.camera(i) for i in range(len(self.start))]

    def apply(self, capture, viewset) -> None:
        """Set the corrected cameras on the capture's frames and the ViewSet's views (every later
        render, re-mesh and material stage takes them from there)."""
        for i, camera in enumerate(self.cameras()):
            capture.frames[i].camera = camera
            v = viewset.views[i]
            viewset.views[i] = dataclasses.replace(v, camera=scaled_camera(camera, v.camera.width, v.camera.height))

    # -- refinement --------------------------------------------------------------------------------
    def refine(self, mesh, material, views: list[View], settings, environment, *, sweeps: int = SWEEPS,
               seed: int = 0, tone: str = "log", intrinsics: bool = True, newton: int = 0, check_stop=None,
               objective_factory=Objective, deadline: float | None = None) -> dict:
        """One refinement of every frame's pose and the intrinsics against ``views`` (the
        capture's frames in order, at one size; their targets as the fit sees them) with
        ``mesh`` and ``material`` frozen (see the module). Updates ``correction``; returns this
        refinement's summary (losses before and after, frames taken back). ``newton`` > 0
        follows the sweeps with that many Gauss-Newton steps on each frame's pose
        (``camera_newton``; the intrinsics held), in ``newton_order`` and only while they pay
        (``NEWTON_GAIN``, see there). ``deadline`` (a ``time.perf_counter()``
        reading; None: none): the sweeps after the first stop once half the time to it is spent
        (all of it without Gauss-Newton steps), and the steps stop at frames not yet begun once
        it is near; the final loss evaluation, which costs about the first's, is held back from it."""
        n = len(views)
        began = time.perf_counter()
        base = [dataclasses.replace(v, camera=scaled_camera(self.start[i], v.camera.width, v.camera.height))
                for i, v in enumerate(views)]
        objective = objective_factory(mesh, material, base, settings, environment, tone=tone)
        renderer = objective.renderer
        lights = [list(ls) for ls in renderer.lights]
        world_map = environment is not None and environment.frame == "world"
        points = np.asarray(mesh.vertices, np.float64)
        before = self.correction.copy()
        k = self.correction.copy()
        f = float(np.mean([b.camera.fx for b in base]))
        radius = 0.5 * float(np.mean([max(b.camera.width, b.camera.height) for b in base]))
        lr_pose = STEP_PX / f
        lr_focal = STEP_PX / max(radius * 0.5, 1.0)
        adam_om = [_Adam(3) for _ in range(n)]
        adam_phi = [_Adam(2) for _ in range(n)]
        adam_dolly = [_Adam(()) for _ in range(n)]
        adam_f, adam_p = _Adam(()), _Adam(2)

        def place(i: int, corr: Correction) -> np.ndarray:
            m, b, parts = vertex_map(base[i].camera, *self.pose(i, corr), corr.sigma, corr.principal)
            if lights[i]:
                renderer.lights[i] = [dataclasses.replace(light, position=m @ np.asarray(light.position, np.float64) + b)
                                      for light in lights[i]]
                renderer._light_view = None
            if world_map:
                rc, _, rd = parts[:3]
                rig = np.eye(4)
                rig[:3, :3] = rc @ rd.T @ rc.T  # the rigid part: the map turns with the object
                renderer.rig = [rig @ environment_to_world(environment.rotation_z_deg)] * len(base)
                renderer._rig_view = None
            return points @ m.T + b, parts

        def loss_of(i: int, corr: Correction) -> float:
            q, _ = place(i, corr)
            return objective.loss(q, [i], seed_for(seed, 7_777_777, 0) - i, None)

        start_loss = np.array([loss_of(i, k) for i in range(n)])
        l0 = np.maximum(start_loss, 1e-12)
        evaluation = time.perf_counter() - began
        end_by = None if deadline is None else deadline - evaluation
        sweeps_by = None if end_by is None else (began + 0.5 * (end_by - began) if newton > 0 else end_by)
        sweeps_run = newton_frames = 0
        for sweep in range(sweeps):
            if sweep and sweeps_by is not None and time.perf_counter() > sweeps_by:
                break
            sweeps_run += 1
            decay = 1.0 - 0.9 * sweep / max(sweeps - 1, 1)
            g_sigma, g_a = 0.0, np.zeros(2)
            for i in range(n):
                if check_stop is not None:
                    check_stop()
                q, parts = place(i, k)
                loss, grad, _ = objective.loss_and_grad(q, [i], seed_for(seed, sweep, i), True, False)
                if not (np.isfinite(loss) and np.all(np.isfinite(grad))):
                    continue
                d_eps, d_t, d_sigma, d_a = chain(grad, points, parts, k.sigma)
                r_delta, t = parts[2], parts[3]
                d = self.distance[i]
                d_eps = d_eps + PRIOR * l0[i] * log_rotation(r_delta) / SIGMA_ROT**2
                d_t = d_t + PRIOR * l0[i] * t / (d * SIGMA_T) ** 2
                g_om, g_phi, g_dolly = pose_grads(d_eps, d_t, k.omega[i], k.phi[i], float(k.dolly[i]), self.focus[i])
                lr = lr_pose * decay
                k.omega[i] = log_rotation(rotation(k.omega[i]) @ rotation(adam_om[i].step(g_om, lr)))
                k.phi[i] = k.phi[i] + adam_phi[i].step(g_phi, lr)
                k.dolly[i] = k.dolly[i] + adam_dolly[i].step(g_dolly, lr)
                g_sigma += d_sigma
                g_a += d_a
            mean_l0 = float(l0.mean())
            g_sigma += n * PRIOR * mean_l0 * k.sigma / SIGMA_F**2
            g_a += n * PRIOR * mean_l0 * k.principal * f**2 / SIGMA_PP**2
            if intrinsics:
                k.sigma = float(k.sigma + adam_f.step(g_sigma, lr_focal * decay))
                k.principal = k.principal + adam_p.step(g_a, lr_pose * decay)
            k.clamp()
        newton_start = time.perf_counter()
        gains, newton_stopped = [], None
        probed = {}  # a probe frame's loss after its steps: its end loss (only its own pose moved since)
        for i in (newton_order(n) if newton > 0 else []):
            if end_by is not None and time.perf_counter() > end_by:
                newton_stopped = "deadline"
                break
            probing = len(gains) < NEWTON_PROBE
            if not probing and float(np.mean(gains)) < NEWTON_GAIN:
                newton_stopped = "gain"
                break
            self._newton(i, k, newton, objective, base[i].camera, place, points, float(l0[i]), settings.spp, seed,
                         check_stop)
            if probing:
                probed[i] = loss_of(i, k)
                gains.append(float(1.0 - probed[i] / l0[i]))
            newton_frames += 1
        newton_seconds = time.perf_counter() - newton_start
        end_loss = np.array([(probed[i] if i in probed else loss_of(i, k)) if k.finite() else np.nan
                             for i in range(n)])
        worse = ~np.isfinite(end_loss) | (end_loss > start_loss * WORSE)
        if not k.finite() or worse.all():
            self.correction, self.diverged = before, True
            end_loss = start_loss
        else:
            k.take_back(worse, before)
            self.correction, self.diverged = k, False
            end_loss = np.where(worse, start_loss, end_loss)
        for i in range(n):  # the renderer is the refinement's own; leave its lights as given
            renderer.lights[i] = lights[i]
        self.refinements += 1
        self.reverted += int(worse.sum())
        record = {"size": int(max(base[0].camera.width, base[0].camera.height)), "sweeps": sweeps_run,
                  "newton": int(newton), "newton_frames": newton_frames, "newton_seconds": round(newton_seconds, 2),
                  "newton_gain": round(float(np.mean(gains)), 6) if gains else None, "newton_stopped": newton_stopped,
                  "seconds": round(time.perf_counter() - began, 2),
                  "loss_start": float(start_loss.mean()), "loss_end": float(end_loss.mean()),
                  "frames_kept_back": int(worse.sum()), "diverged": self.diverged}
        self.history.append(record)
        return record

    def _newton(self, i: int, k: Correction, steps: int, objective, camera: Camera, place, points: np.ndarray,
                l0: float, spp: int, seed: int, check_stop) -> None:
        """``steps`` Gauss-Newton steps on frame ``i``'s pose in ``k`` (``camera_newton``): a step
        is kept only when the loss (the same seed and samples before and after) plus the prior
        falls; a rejected step is retried once at ``BACKTRACK`` of its length. The prior is the
        sweeps' scaled by ``STEP_PRIOR`` with the frame's loss when the steps begin (at most
        ``l0``) as its unit."""
        focus, distance = self.focus[i], float(self.distance[i])
        weight = [gn.STEP_PRIOR * PRIOR * l0]

        def prior(p):
            return gn.prior_residual(p, focus, distance, weight[0], SIGMA_ROT, SIGMA_T)

        def moved(p):
            m, b, _ = vertex_map(camera, *delta(p[:3], p[3:5], float(p[5]), focus), k.sigma, k.principal)
            return points @ m.T + b

        spp_hi = gn.RESIDUAL_SPP * spp
        for step in range(steps):
            if check_stop is not None:
                check_stop()
            p = gn.pose_vector(k, i)
            seed_r, seed_j = seed_for(seed, 5_000_000 + step, i), seed_for(seed, 6_000_000 + step, i)
            q, _ = place(i, k)
            res = gn.residual(objective, i, q, seed_r, spp_hi)
            jac = gn.image_jacobian(objective, i, q, np.moveaxis(gn.jacobian_fd(moved, p), -1, 0), seed_j)
            if not (np.all(np.isfinite(res)) and np.all(np.isfinite(jac))):
                return
            if step == 0:  # near the optimum the prior's weight follows the loss there, not the start's
                weight[0] = gn.STEP_PRIOR * PRIOR * min(l0, float(np.mean(res**2)))
            e, jac_e = prior(p), gn.jacobian_fd(prior, p)
            current = float(np.mean(res**2) + 0.5 * e @ e)
            dp = gn.lm_step(jac, res, e, jac_e, gn.LAMBDA0)
            for scale in (1.0, gn.BACKTRACK):
                trial = k.copy()
                gn.set_pose(trial, i, p + scale * dp)
                trial.clamp()
                pt = gn.pose_vector(trial, i)
                qt, _ = place(i, trial)
                et = prior(pt)
                new = float(np.mean(gn.residual(objective, i, qt, seed_r, spp_hi) ** 2) + 0.5 * et @ et)
                if np.isfinite(new) and new < current:
                    gn.set_pose(k, i, pt)
                    break
        place(i, k)

    # -- outputs -----------------------------------------------------------------------------------
    def state(self) -> dict:
        return {"correction": self.correction.to_json(), "refinements": self.refinements,
                "reverted": self.reverted, "diverged": self.diverged, "history": self.history}

    def restore(self, state: dict | None) -> None:
        if state:
            self.correction = Correction.from_json(state["correction"])
            self.refinements, self.reverted = int(state["refinements"]), int(state["reverted"])
            self.diverged, self.history = bool(state["diverged"]), list(state["history"])

    def cameras_json(self) -> dict:
        """RUN/cameras.json: the refined cameras as capture.json writes cameras, by frame name."""
        cams = self.cameras()
        for c in cams:
            if not (np.all(np.isfinite(c.camera_to_world)) and all(np.isfinite([c.fx, c.fy, c.cx, c.cy]))):
                raise ValueError("a refined camera is not finite")
        return {"format": FORMAT, "frames": [{"name": n, "camera": c.to_json()} for n, c in zip(self.names, cams)]}

    def report(self, points: np.ndarray, held_out: bool) -> dict:
        """report.json ``cameras_refined``: how far the cameras moved (rotation in degrees,
        translation in % of the camera's distance, the mesh's reprojection in pixels of the
        frames), the intrinsic corrections, and what was kept back."""
        k = self.correction
        cams = self.cameras()
        poses = [self.pose(i) for i in range(len(self.start))]
        rot = np.degrees([np.linalg.norm(log_rotation(r)) for r, _ in poses])
        trans = 100.0 * np.array([np.linalg.norm(t) for _, t in poses]) / self.distance
        pts = np.asarray(points, np.float64)
        if len(pts) > 2000:
            pts = pts[np.linspace(0, len(pts) - 1, 2000).astype(int)]
        reproj = np.array([reprojection_px(s, c, pts) for s, c in zip(self.start, cams)])

        def stats(a):
            return {"mean": round(float(a.mean()), 5), "max": round(float(a.max()), 5)}

        f0 = float(np.mean([c.fx for c in self.start]))
        out = {"refined": True, "refinements": self.refinements, "file": FILENAME,
               "rotation_deg": stats(rot), "translation_pct": stats(trans), "reprojection_px": stats(reproj),
               "focal_scale": round(float(np.exp(k.sigma)), 6),
               "principal_point_px": [round(float(k.principal[0] * f0), 4), round(float(k.principal[1] * f0), 4)],
               "prior": {"weight": PRIOR, "sigma_rotation_deg": 1.0, "sigma_translation_pct": 100 * SIGMA_T,
                         "sigma_focal": SIGMA_F, "sigma_principal_px": SIGMA_PP},
               "frames_kept_back": self.reverted, "diverged": self.diverged, "history": self.history}
        if self.diverged:
            out["note"] = "the last refinement diverged: it kept the cameras it started from"
        if held_out:
            out["held_out"] = ("kept as given: refining a held-out view's pose would fit its pixels "
                               "(the shared intrinsics are not applied to them either)")
        return out


def newton_order(n: int) -> list[int]:
    """Frames 0..n-1 interleaved by ``NEWTON_STRIDE`` (0, 8, 16, ..., 1, 9, ...): any prefix of
    the order spans the capture, so the frames a deadline or the gain rule leaves out are
    spread over it rather than its end."""
    return [i for r in range(NEWTON_STRIDE) for i in range(r, n, NEWTON_STRIDE)]


class CameraRefinement:
    """``--refine-cameras`` in a run: when it refines (after every geometry level from the second
    on, ``FIRST_LEVEL``), on what, and what it writes (RUN/cameras.json, report.json
    ``cameras_refined``). Geometry and material are frozen during its steps.

    Args:
        capture: the capture the run fits (held-out views already left out).
        config: the run's ReconstructConfig.
        viewset: the run's views (their cameras are replaced by the refined ones).
    """

    FIRST_LEVEL = 1  # the coarsest level's surface is too rough to register against

    def __init__(self, capture, config, viewset):
        self.capture, self.config, self.viewset = capture, config, viewset
        centre, _ = capture.bounds_hint()
        self.fit = CameraFit([f.name for f in capture.frames], [f.camera for f in capture.frames], centre)

    @classmethod
    def start(cls, capture, config, viewset) -> "CameraRefinement | Unrefined":
        """The refinement ``config.refine_cameras`` asks for on ``capture`` (``enabled``), else
        one that does nothing."""
        max_size = getattr(config, "max_size", None)
        if enabled(config.refine_cameras, capture, max_size):
            return cls(capture, config, viewset)
        return Unrefined(config, unmeasurable(capture, max_size) if config.refine_cameras == "auto" else None)

    # A refinement lowering the mean loss by less than this share leaves the cameras settled: the
    # later levels do not refine again (one at twice the size costs about four times as much).
    SETTLED_GAIN = 0.003
    # The most of the time left (to the budget's end, results excluded) one refinement may take.
    TIME_SHARE = 0.25

    def due(self, level: int) -> bool:
        return level >= self.FIRST_LEVEL

    def settled(self) -> bool:
        """Whether the last refinement gained less than ``SETTLED_GAIN`` of its starting loss."""
        if not self.fit.history:
            return False
        last = self.fit.history[-1]
        start, end = float(last["loss_start"]), float(last["loss_end"])
        return not last["diverged"] and start > 0 and (start - end) / start < self.SETTLED_GAIN

    def deadline(self, budget) -> float | None:
        """The ``time.perf_counter()`` reading by which a refinement starting now ends: ``TIME_SHARE``
        of the time the budget has left (None without a time budget)."""
        left = budget.seconds_left()
        return None if left is None else time.perf_counter() + self.TIME_SHARE * left

    def after_level(self, state, material, views, settings, environment, budget, emit, check_stop) -> None:
        """After a level (``state``: the run's RunState): one refinement against ``views`` (the
        level's) with the level's geometry ``settings`` and ``environment``, when due, the
        cameras are not settled (``settled``) and the budget allows, within ``deadline``; the
        cameras are then set everywhere and a ``cameras`` event sent."""
        if not self.due(state.level) or self.settled() or budget.out(budget.geometry_reserve()):
            return
        start = time.perf_counter()
        record = self.fit.refine(state.mesh, material, views, settings, environment, sweeps=self.config.camera_sweeps,
                                 newton=self.config.camera_newton, deadline=self.deadline(budget),
                                 seed=self.config.seed + state.level, tone=self.config.tone, check_stop=check_stop)
        self.apply()
        state.timed("cameras", start)
        moved = self.fit.report(state.mesh.vertices, held_out=False)
        emit("cameras", level=state.level, **record, reprojection_px=moved["reprojection_px"]["mean"],
             rotation_deg=moved["rotation_deg"]["mean"], translation_pct=moved["translation_pct"]["mean"])
        if record["diverged"]:
            emit("warning", message="camera refinement diverged: the cameras it started from are kept")

    def apply(self) -> None:
        if self.fit.correction.finite():
            self.fit.apply(self.capture, self.viewset)

    def state(self) -> dict:
        return self.fit.state()

    def restore(self, state: dict | None) -> None:
        self.fit.restore(state)
        self.apply()

    def finish(self, folder, mesh, held_out: bool) -> dict:
        """Write RUN/cameras.json (when a refinement kept a correction) and return report.json's
        ``cameras_refined``."""
        if self.fit.refinements == 0:
            return {"refined": False, "mode": self.config.refine_cameras,
                    "note": "no refinement ran (it begins after the second geometry level)"}
        out = self.fit.report(mesh.vertices, held_out)
        if self.settled():
            out["settled"] = (f"the last refinement lowered the loss by less than {100 * self.SETTLED_GAIN:g} %: "
                              "later levels did not refine again")
        try:
            fsio.write_json(folder / FILENAME, self.fit.cameras_json())
        except ValueError:
            out.update(refined=False, diverged=True, note="a refined camera was not finite: the starting cameras were kept")
        return {**out, "mode": self.config.refine_cameras}


class Unrefined:
    """The cameras of a run that does not refine them: as given (``CameraRefinement``'s methods)."""

    def __init__(self, config, note: str | None = None):
        self.mode, self.note = config.refine_cameras, note  # note: why ``auto`` left solved cameras alone

    def after_level(self, *args) -> None:
        pass

    def state(self) -> None:
        return None

    def restore(self, state) -> None:
        pass

    def finish(self, folder, mesh, held_out: bool) -> dict:
        return {"refined": False, "mode": self.mode, **({"note": self.note} if self.note else {})}
