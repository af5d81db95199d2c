"""``LevelRun`` and ``PolishRun``: one run of vertex steps at one image size, on a ``Fit``
(the run's inputs and state); the rules of each: their class docstrings."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..capture.model import Capture
from ..geometry.mesh import Mesh
from ..geometry.topology import enclosed, mean_edge_length
from ..render.scene import RenderSettings
from .appearance import lit_environment
from .budget import Budget
from .config import ReconstructConfig
from .convergence import Plateau, level_size
from .objective import Objective, seed_for
from .progress import Progress
from .records import LevelRecord, RunState
from .shadow_samples import ShadowSamples
from .steps import Adam, VertexOptimizer, clip_outliers, finite
from .views import ViewSet, validation_views


@dataclass
class Fit:
    """What a level, a polish round and a transition work on; ``state`` and ``material``
    change in place."""

    capture: Capture
    config: ReconstructConfig
    state: RunState
    viewset: ViewSet
    material: object  # the run's material model
    budget: Budget
    stiffness: object  # optimize.stiffness.choose's Stiffness
    settings: RenderSettings  # the geometry steps' render settings
    emit: Callable
    progress: Progress
    check_stop: Callable[[], None]  # raises StopRequested when a stop was asked for
    # checkpoint(vertices, loss, validation loss): the run's snapshot and held-out score when due
    checkpoint: Callable[[np.ndarray, float, float | None], None]
    objective_factory: Callable = Objective
    # after each geometry step: the render settings later steps take when they change (the
    # first decision's deferred cost probe, ``Appearance.run_pending_costs``), else None
    after_step: Callable[[int], RenderSettings | None] = lambda geometry_steps: None


def latents(material) -> dict[str, np.ndarray]:
    """A copy of the material's parameters (float64)."""
    return {n: np.array(z, np.float64) for n, z in material.parameters().items()}


def skip(state: RunState, emit, why: str) -> None:
    """Count a skipped step and warn of it."""
    state.skipped += 1
    emit("warning", message=f"step {state.iteration} skipped: {why} ({state.skipped} so far)")


class LevelRun:
    """One geometry level on ``fit``; call it once for its LevelRecord (appended to
    ``fit.state.levels``); ``validation`` is then its last validation loss.

    A level optimises the vertices (Laplacian-preconditioned steps, several views per step,
    fixed seeds) with joint material steps, halves its step when the validation loss plateaus
    and backtracks to its best surface when the loss rises by ``backtrack``; after a backtrack
    the material steps stop first.

    A polish round starts from a converged surface under the finished material, which stays
    frozen (noisy joint steps would blur the fitted textures). There single validation losses
    swing by several per cent between evaluations while held-out views keep improving, so a
    round grows into its step over ``polish_warmup`` steps and keeps it; it backtracks only when
    a loss is ``polish_divergence`` above the best, and ends when the mean of the last
    ``polish_window`` losses stops setting new bests.
    """

    stage = "geometry"
    material_steps = True  # joint material steps (until the first backtrack)

    def __init__(self, fit: Fit):
        self.fit, self.config, self.state = fit, fit.config, fit.state
        self.validation: float | None = None

    # -- what differs between levels and polish rounds ---------------------------------------------
    def patience(self) -> int:
        return self.config.patience

    def limit(self) -> int:
        return self.state.level_limit or self.config.level_iterations

    def reserve(self) -> float:
        return self.fit.budget.geometry_reserve()

    def warmup(self) -> int:
        """Material-only steps that open level 0 when the material is estimated: a wrong
        material makes the geometry compensate (a too-dark material inflates the mesh
        toward the lights), so the material gets a head start."""
        if self.state.level != 0 or not self.fit.material.trainable:
            return 0
        cap = self.config.iterations  # a capped run keeps most of its steps for geometry
        return self.config.material_warmup if cap is None else min(self.config.material_warmup, cap // 3)

    def before_step(self) -> None:
        pass

    def step_final(self) -> float:
        return self.opt.lr / self.lr0

    def evaluate(self, val: float, vertices: np.ndarray, geometry: bool, warmup: int):
        """Act on a validation loss; returns (vertices, whether the run ends)."""
        c, opt, plateau = self.config, self.opt, self.plateau
        if plateau.update(val):
            self.best = (vertices.copy(), latents(self.fit.material))
        elif val > plateau.best * (1 + c.backtrack) or not math.isfinite(val):
            vertices = self.best[0].copy()  # backtrack: the step was too long
            self.fit.material.load_parameters(self.best[1])
            opt.set_vertices(vertices)
            opt.reset_moments()
            if self.joint and geometry:
                # the material's steps are the first suspects: Adam moves every mesh-color
                # sample by about its step, noise or not, which undoes a fitted texture. The
                # level goes on with the material frozen
                self.joint, self.frozen_at = False, self.state.level_iteration
            else:
                opt.lr *= 0.5
        settled = self.state.level_iteration >= c.min_level_iterations + warmup
        if plateau.converged and settled:
            if opt.lr <= self.lr0 * c.min_step_scale * 1.0001:
                return vertices, True
            opt.lr *= 0.5
            plateau.stale = 0
        return vertices, False

    # -- the steps ------------------------------------------------------------------------------
    def __call__(self) -> LevelRecord:
        fit, c, s = self.fit, self.config, self.state
        start = time.perf_counter()
        size = level_size(s.level, c.coarse_size, c.max_size)
        views = fit.viewset.at(size)
        centres = np.array([v.camera.centre for v in views])
        environment = lit_environment(fit.capture, fit.material)
        settings = fit.settings
        objective = fit.objective_factory(s.mesh, fit.material, views, settings, environment, tone=c.tone)
        # shadow-gradient samples this level affords: timed on its own first steps
        shadows = ShadowSamples(settings.sppi if hasattr(objective, "set_shadow_samples") else 0)
        self.lr0 = c.step * mean_edge_length(s.mesh)
        self.opt = opt = VertexOptimizer(s.mesh.vertices, s.mesh.faces, fit.stiffness.lambda_, self.lr0)
        material_opt = Adam(c.material_lr)
        val_ids = validation_views(len(views), c.validation_views)
        val_seed = seed_for(c.seed, 10_000_019, 0)
        self.plateau = plateau = Plateau(c.plateau_tolerance, self.patience())
        self.full, self.recent = self.lr0, []  # a polish round's step and its validation losses
        limit = self.limit()
        vertices = s.mesh.vertices.copy()
        self.validation = objective.validation_loss(vertices, val_ids, val_seed, c.validation_spp)
        plateau.update(self.validation)
        fit.emit("stage", stage=self.stage, level=s.level, faces=s.mesh.n_faces, iteration=s.iteration,
                 loss=plateau.best, size=size, seconds=round(fit.budget.elapsed(), 3),
                 environment_strength=None if environment is None else environment.strength)
        self.best = (vertices.copy(), latents(fit.material))
        first_loss = plateau.best
        rng = np.random.default_rng([c.seed, s.level])
        order: list[int] = []
        warmup = self.warmup() if self.material_steps else 0
        s.level_iteration = 0
        self.joint, self.frozen_at = self.material_steps, None
        self.shadows = None
        try:
            while s.level_iteration < limit:
                fit.check_stop()
                if fit.budget.out(self.reserve()):
                    break
                ids = []
                while len(ids) < min(c.views_per_step, len(views)):
                    if not order:
                        order = list(rng.permutation(len(views)))
                    ids.append(int(order.pop()))
                geometry = s.level_iteration >= warmup
                self.before_step()
                sppi = shadows.next_count() if geometry and shadows.active else None
                if sppi is not None:
                    objective.set_shadow_samples(sppi)
                step_start = time.perf_counter()
                loss, grad, mgrads = objective.loss_and_grad(vertices, ids, seed_for(c.seed, s.iteration, 0),
                                                             geometry, self.joint)
                if sppi is not None and shadows.record(sppi, time.perf_counter() - step_start):
                    objective.set_shadow_samples(shadows.chosen)
                    self.shadows = shadows.to_json()
                    fit.emit("shadow_samples", stage=self.stage, level=s.level, faces=s.mesh.n_faces, size=size,
                             **self.shadows)
                s.iteration += 1
                s.level_iteration += 1
                if not (math.isfinite(loss) and finite(*([grad] if geometry else []), *mgrads.values())):
                    skip(s, fit.emit, "non-finite loss or gradient")
                    continue
                if geometry:
                    new_vertices = opt.step(clip_outliers(grad, fit.stiffness.clip))
                    if not finite(new_vertices):
                        opt.set_vertices(vertices)
                        skip(s, fit.emit, "non-finite vertex positions after a step")
                        continue
                    if enclosed(Mesh(new_vertices, s.mesh.faces), centres).any():
                        # no silhouette left to render from inside: the step was too long
                        opt.set_vertices(vertices)
                        opt.reset_moments()
                        opt.lr *= 0.5
                        self.full *= 0.5
                        skip(s, fit.emit, "the step put a camera inside the mesh (step halved)")
                        continue
                    vertices = new_vertices
                if mgrads:
                    trainable = {n: z for n, z in latents(fit.material).items() if n in mgrads}
                    fit.material.load_parameters(material_opt.step(trainable, mgrads))
                fit.progress.update(stage=self.stage, level=s.level, iteration=s.level_iteration,
                                    iterations=limit, loss=loss, faces=s.mesh.n_faces)
                if s.level_iteration % c.eval_every == 0:
                    val = self.validation = objective.validation_loss(vertices, val_ids, val_seed, c.validation_spp)
                    vertices, done = self.evaluate(val, vertices, geometry, warmup)
                    if done:
                        break
                fit.checkpoint(vertices, loss, self.validation)
                changed = fit.after_step(s.level_iteration - warmup) if geometry else None
                if changed is not None and changed != settings:
                    # new settings: a new objective, and the plateau restarts from its loss (a
                    # deeper path or shadow samples change what the loss measures)
                    settings = changed
                    objective = fit.objective_factory(Mesh(vertices, s.mesh.faces), fit.material, views, settings,
                                                      environment, tone=c.tone)
                    shadows = ShadowSamples(settings.sppi if hasattr(objective, "set_shadow_samples") else 0)
                    self.validation = objective.validation_loss(vertices, val_ids, val_seed, c.validation_spp)
                    plateau = self.plateau = Plateau(c.plateau_tolerance, self.patience())
                    plateau.update(self.validation)
                    self.best = (vertices.copy(), latents(fit.material))
        finally:
            if shadows.chosen is not None:  # what the kept count cost over all of the level's steps
                self.shadows = shadows.to_json()
            # keep the best surface found so far, also when cancelled
            s.mesh = Mesh(self.best[0], s.mesh.faces)
            fit.material.load_parameters(self.best[1])
            s.timed(self.stage, start)
        record = LevelRecord(level=s.level, size=size, faces=s.mesh.n_faces, iterations=s.level_iteration,
                             loss_start=first_loss, loss=plateau.best, step_final=self.step_final(),
                             material_frozen_at=self.frozen_at, seconds=round(time.perf_counter() - start, 3),
                             elapsed=round(fit.budget.elapsed(), 3), polish=not self.material_steps,
                             shadow_samples=self.shadows)
        s.levels.append(record)
        return record


class PolishRun(LevelRun):
    """One polish round: the material frozen, a steady step (see ``LevelRun``)."""

    stage = "polish"
    material_steps = False

    def patience(self) -> int:
        return self.config.polish_patience

    def limit(self) -> int:
        return self.config.level_iterations * self.config.polish_length

    def reserve(self) -> float:
        return self.fit.budget.polish_reserve()

    def before_step(self) -> None:
        self.opt.lr = self.full * min(1.0, (self.state.level_iteration + 1) / max(self.config.polish_warmup, 1))

    def step_final(self) -> float:
        return self.full / self.lr0

    def evaluate(self, val: float, vertices: np.ndarray, geometry: bool, warmup: int):
        c, opt, plateau = self.config, self.opt, self.plateau
        if val > plateau.best * (1 + c.polish_divergence) or not math.isfinite(val):
            vertices = self.best[0].copy()  # diverged: back to the last surface checked
            opt.set_vertices(vertices)
            opt.reset_moments()
            self.full *= 0.5
        else:
            self.best = (vertices.copy(), self.best[1])
            self.recent.append(val)
            plateau.update(float(np.mean(self.recent[-c.polish_window:])))
            if plateau.converged:
                return vertices, True
        return vertices, False
