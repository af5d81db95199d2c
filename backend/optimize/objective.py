"""The objective: masked squared error between path-traced renders and the target views,
through a log tone curve (the reasons: ``Objective``)."""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager, nullcontext

import drjit as dr
import mitsuba as mi
import numpy as np

from ..geometry.mesh import Mesh
from ..render.scene import RenderSettings, SceneRenderer
from .views import View

VERTICES = "object.vertex_positions"


def seed_for(run_seed: int, step: int, view: int) -> int:
    """Distinct, reproducible sampler seeds for every (run, step, view)."""
    return (run_seed * 1_000_003 + step * 1009 + view) % (1 << 31)


class GradientRenderer(SceneRenderer):
    """A SceneRenderer whose differentiable renders use the integrator's own sample counts
    (``sppc`` for the interior, ``sppp`` for silhouettes) rather than one runtime count; the
    primal image takes the sensors' count (``RenderSettings.primal_spp`` for a projective
    integrator, else ``spp``)."""

    def render_split(self, view: int, seed: int, params):
        self._set_lights(view)
        self._set_rig(view)
        return mi.render(self.scene, params, sensor=self.sensors[view], seed=seed, spp=0)


class StepTimer:
    """Seconds of a step's parts, summed over the steps timed: each part ends in a sync, so
    the work a part launches is charged to it (the syncs change the overlap between parts,
    not their work). ``Objective.timer`` takes one; ``bench steps`` prints the split."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def part(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            dr.sync_thread()
            self.seconds[name] += time.perf_counter() - start


def tone_scale(views: list[View]) -> float:
    """Mean radiance over the targets' object pixels (the tone curve's knee)."""
    values = [v.target[(v.mask > 0.5) if v.mask is not None else (v.target.max(-1) > 0)] for v in views]
    values = np.concatenate([x.ravel() for x in values if x.size])
    return float(max(values.mean(), 1e-6)) if values.size else 1.0


class Objective:
    """Loss and gradients for one mesh connectivity at one image size.

    With emitters hidden, a render is black outside the object, so the squared error against
    mask x image over the whole frame is the paper's masked loss (silhouette errors included).
    Projective integrators give the silhouette gradients.

    By default both images pass through the tone curve t(x) = log(1 + x / s) first (s = the
    mean object radiance of the targets). Plain MSE (``tone="linear"``, the paper's loss) lets
    specular highlights dominate: its per-vertex gradient is heavy-tailed (a few vertices carry
    most of its energy) and gradients of two seeds barely agree; the log curve evens both out.
    """

    def __init__(self, mesh: Mesh, material, views: list[View], settings: RenderSettings,
                 environment=None, env_pixels: np.ndarray | None = None, tone: str = "log"):
        self.material = material
        self.views = views
        self.settings = settings
        self.renderer = GradientRenderer(mesh, material.field, [v.camera for v in views], [v.lights for v in views],
                                         environment, settings, env_pixels=env_pixels)
        self.scale = tone_scale(views) if tone == "log" else None
        self.targets = [mi.TensorXf(np.ascontiguousarray(self._tone_np(v.target), np.float32)) for v in views]
        self.targets_np = [self._tone_np(np.asarray(v.target, np.float32)) for v in views]
        self.timer: StepTimer | None = None  # times the parts of each gradient step when set

    def _part(self, name: str):
        return nullcontext() if self.timer is None else self.timer.part(name)

    def _tone(self, img):
        return img if self.scale is None else dr.log(1.0 + dr.maximum(img, 0.0) * (1.0 / self.scale))

    def _tone_np(self, img: np.ndarray) -> np.ndarray:
        return img if self.scale is None else np.log1p(np.maximum(img, 0.0) / self.scale)

    def set_shadow_samples(self, sppi: int) -> None:
        """Indirect-visibility samples per pixel of the next gradients (optimize.shadow_samples);
        only a projective integrator built with shadow gradients has them."""
        integrator = self.renderer.scene.integrator()
        if self.settings.sppi > 0 and hasattr(integrator, "sppi"):
            integrator.sppi = int(sppi)

    def _set_vertices(self, vertices) -> None:
        self.renderer.params[VERTICES] = vertices
        self.renderer.params.update()

    def loss_and_grad(self, vertices: np.ndarray, view_ids: list[int], step_seed: int, geometry: bool = True,
                      material: bool = True) -> tuple[float, np.ndarray | None, dict[str, np.ndarray]]:
        """Mean masked MSE over ``view_ids`` and its gradients: (loss, dLoss/dvertices (V, 3),
        {trainable material latent: gradient}, empty when ``material`` is False)."""
        with self._part("scene update"):
            v = mi.Float(np.asarray(vertices, np.float32).ravel())
            if geometry:
                dr.enable_grad(v)
            self._set_vertices(v)
        latents = self.material.parameters()
        trainable = {n: latents[n] for n in self.material.trainable} if material else {}
        for z in trainable.values():
            dr.enable_grad(z)
        params = self.material.attach(self.renderer.params)
        total = 0.0
        for k, view in enumerate(view_ids):
            if k and geometry:
                # the last backward pass used up the graph from v to the vertex normals: rebuild
                # the normals alone (the positions, and so the scene's BVH, are unchanged; a full
                # update rebuilt the BVH, 0.16 s at 170k faces)
                with self._part("scene update"):
                    self.renderer.object.recompute_vertex_normals()
            with self._part("forward"):
                img = self.renderer.render_split(view, seed=step_seed + k, params=params)
                loss = dr.mean(dr.square(self._tone(img) - self.targets[view]), axis=None).array / len(view_ids)
                if self.timer is not None:
                    dr.eval(loss)
            # one backward pass per view: the integrator re-traces the scene when differentiating,
            # so it must happen while this view's lights are still in place
            with self._part("backward"):
                dr.backward(loss)
            with self._part("read-back"):
                total += float(loss[0])
        with self._part("read-back"):
            grad_v = np.array(dr.grad(v), np.float64).reshape(-1, 3) if geometry else None
            grads = {n: np.array(dr.grad(z), np.float64) for n, z in trainable.items()}
        for z in trainable.values():
            dr.disable_grad(z)
        return total, grad_v, grads  # the scene keeps v: every call sets its own vertices first

    def loss(self, vertices: np.ndarray, view_ids: list[int], seed: int, spp: int | None = None) -> float:
        """Mean masked MSE without gradients (fixed seed: comparable between calls)."""
        self._set_vertices(mi.Float(np.asarray(vertices, np.float32).ravel()))
        total = 0.0
        with dr.suspend_grad():
            for view in view_ids:
                img = self._tone_np(np.array(self.renderer.render(view, seed=seed + view, spp=spp)))
                total += float(np.mean((img - self.targets_np[view]) ** 2))
        return total / len(view_ids)

    def validation_loss(self, vertices: np.ndarray, view_ids: list[int], seed: int, spp: int | None = None) -> float:
        """The squared error of the *expected* render, without the render's own noise: two
        renders a, b at half the samples each, with independent seeds, estimate it as
        mean((t(a) - t(y)) (t(b) - t(y))), since the noise of a and b is uncorrelated.

        The plain error also holds the render's variance, which at low spp can exceed the
        surface's and material's own error, so convergence tests (relative gains) would see
        a fraction of the real one. The estimate is held at 1/20 of the plain
        error or above: below that the noise cannot tell surfaces apart."""
        self._set_vertices(mi.Float(np.asarray(vertices, np.float32).ravel()))
        half = max(1, (spp or self.settings.spp) // 2)
        cross = plain = 0.0
        with dr.suspend_grad():
            for view in view_ids:
                target = self.targets_np[view]
                a, b = (self._tone_np(np.array(self.renderer.render(view, seed=s, spp=half))) - target
                        for s in (seed + view, seed + view + 7919))
                cross += float(np.mean(a * b))
                plain += float(np.mean(a * a + b * b)) / 2
        return max(cross, plain / 20) / len(view_ids)
