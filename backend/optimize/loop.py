"""The reconstruction loop: initialise, then alternate optimisation levels and refinement.

A level optimises the vertices (Laplacian-preconditioned steps, several views per step,
fixed seeds) at one image size until the validation loss plateaus; steps are backtracked
when the validation loss rises. Between levels the mesh is re-meshed (ray casting +
screened Poisson; the material restarts from grey) when it has become inconsistent,
subdivided 1-to-4 and simplified to the face budget (the material carried over). Levels
continue until one stops improving (schedule.keeps_improving), the time budget or the
iteration cap runs out, or a stop is requested."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from ..capture.model import Capture
from ..errors import InputError
from ..geometry.init import initial_mesh
from ..geometry.mesh import Mesh, load_mesh, save_mesh
from ..geometry.poisson import SurfaceReconstructionError
from ..geometry.remesh import poisson_from_samples, visible_samples
from ..geometry.simplify import FaceBudget
from ..geometry.subdivide import midpoint
from ..geometry.topology import enclosed, inspect, mean_edge_length
from ..render.scene import RenderSettings
from .. import fsio
from .appearance import Appearance, lit_environment
from .config import ReconstructConfig
from .material import ConstantMaterial
from .objective import Objective, seed_for
from .progress import StopOnProgress, LockedEmitter, Progress
from .run_folder import RunFolder, StopRequested
from .schedule import Plateau, keeps_improving, level_size
from .steps import Adam, VertexOptimizer, clip_outliers, finite
from .stiffness import Stiffness, choose as choose_stiffness
from .views import ViewSet, validation_views


class Reconstruction:
    def __init__(self, capture: Capture, folder: RunFolder, config: ReconstructConfig, emit,
                 material=None, resume: bool = False):
        self.capture, self.folder, self.config = capture, folder, config
        emit = StopOnProgress(emit, folder.check_stop, lambda: self.phase != "done")
        self.emit = LockedEmitter(emit)
        self.material = material
        self.resume = resume
        self.t0 = time.perf_counter()
        self.excluded = 0.0  # seconds spent on tracking metrics (not charged to the budget)
        self.before = 0.0  # seconds of the runs this one resumes
        self.mesh: Mesh | None = None
        self.level = 0
        self.iteration = 0  # optimisation steps over all levels
        self.level_iteration = 0
        self.phase = "level"  # where a resume restarts: "level", "transition", "materials" or "polish"
        self.polished = 0  # polish rounds run (see _polish)
        self.budget: FaceBudget | None = None
        self.levels: list[dict] = []
        self.levels_ended: str | None = None  # why the coarse-to-fine levels ended (_levels_end)
        self.skipped = 0
        self.timings: dict[str, float] = {}
        self.init_info: dict = {}
        self.last_snapshot = 0.0
        self.snapshot_seconds = 0.0  # what the last snapshot took to write
        self.viewset = ViewSet(capture, config.max_size)
        self.appearance = Appearance(capture, config, emit)
        self.truth = self._truth()
        self.progress: Progress | None = None
        self.stiffness: Stiffness | None = None

    # -- clocks and limits --------------------------------------------------------------------------
    def elapsed(self) -> float:
        return self.before + time.perf_counter() - self.t0 - self.excluded

    def _fraction(self) -> float:
        c = self.config
        estimates = []
        if c.iterations:
            estimates.append(self.iteration / c.iterations)
        if c.time_budget_s:
            estimates.append(self.elapsed() / c.time_budget_s)
        if not estimates:
            estimates.append((self.level + min(1.0, self.level_iteration / c.level_iterations)) / c.max_levels)
        return min(0.999, max(estimates))

    def _out_of_budget(self, reserve: float = 0.0) -> bool:
        """``reserve``: the share of the time budget held back (for the final material stages)."""
        c = self.config
        return bool((c.time_budget_s and self.elapsed() >= c.time_budget_s * (1.0 - reserve))
                    or (c.iterations and self.iteration >= c.iterations))

    def _geometry_reserve(self) -> float:
        """The share of a time budget the geometry levels leave to the material stages that
        run to convergence on the final geometry (staged materials only)."""
        driver = self.appearance.driver
        return driver.reserve if driver is not None else 0.0

    def _polish_reserve(self) -> float:
        """The share of a time budget polish rounds leave to what follows them: one material
        cycle (``MaterialSchedule.refine``), the specular check and the run's outputs, in units
        of the last material cycle on the final mesh (the driver's share before one has run)."""
        driver, budget = self.appearance.driver, self.config.time_budget_s
        if driver is None:
            return 0.0
        cycles = self.levels[-1].get("material") if self.levels else None
        if not (budget and cycles):
            return driver.polish_reserve
        return driver.polish_reserve_cycles * cycles[-1]["seconds"] / budget

    def _timed(self, name: str, start: float) -> None:
        self.timings[name] = round(self.timings.get(name, 0.0) + time.perf_counter() - start, 3)

    # -- public ---------------------------------------------------------------------------------
    def run(self) -> int:
        """Run to the end; returns the exit code (0 done, 130 cancelled)."""
        with Progress(self.emit, self._fraction, self.elapsed) as self.progress:
            try:
                self._start()
                self._optimise()
            except (KeyboardInterrupt, StopRequested):
                return self._cancel()
            self._finish()
        return 0

    # -- start -------------------------------------------------------------------------------------
    def _check_lights_outside(self, kind: str) -> None:
        """A point light inside the starting surface leaves every render black and every
        gradient zero: such a run would learn nothing and must not end "done"."""
        lights = {tuple(np.round(light.position, 9)) for f in self.capture.frames for light in f.lights}
        if not lights:
            return
        positions = np.array(sorted(lights))
        inside = enclosed(self.mesh, positions)
        if inside.any():
            p = positions[np.argmax(inside)]
            raise InputError(self.capture.root, f"the initial mesh ({kind}) encloses the point light at "
                             f"({p[0]:.3g}, {p[1]:.3g}, {p[2]:.3g}): every render would be black",
                             "start from a mesh that leaves the lights outside (--init sphere or a mesh file), "
                             "or give masks that do not cover the lamp")

    def _start(self) -> None:
        c = self.config
        if self.resume:
            self._load_state()
            return
        start = time.perf_counter()
        self.emit("stage", stage="init", level=0, faces=0)
        self.progress.update(force=True, stage="init", level=0, iteration=0, iterations=0, loss=None, faces=0)
        self.mesh, kind = initial_mesh(self.capture, c.init, c.initial_faces,
                                       warn=lambda message: self.emit("warning", message=message))
        self._check_lights_outside(kind)
        if self.material is None:
            self.material = ConstantMaterial.from_spec(c.material)
        coarse = self.viewset.at(c.coarse_size)
        self.material = self.appearance.initial_material(self.mesh, coarse) or self.material
        self.appearance.decide(self.mesh, self.material, coarse, reason="initial mesh")
        self._choose_stiffness(coarse)
        self.budget = FaceBudget(self.mesh.n_faces, growth=c.face_growth)
        self._timed("init", start)
        report = inspect(self.mesh)
        self.init_info = {"kind": kind, "faces": self.mesh.n_faces, "genus": report.genus,
                          "seconds": round(time.perf_counter() - start, 3)}
        if self.truth is not None:
            self.init_info["metrics"] = self._metrics(self.mesh)
        self._snapshot(loss=None)

    def _load_state(self) -> None:
        state, material_path = self.folder.load_state()
        self.mesh = Mesh(state["vertices"], state["faces"])
        self.material = self._load_material(material_path)
        self.level, self.iteration = state["level"], state["iteration"]
        self.phase = state["phase"]
        self.polished = state.get("polished", 0)
        self.budget = FaceBudget(**state["budget"])
        self.levels, self.skipped = state["levels"], state["skipped"]
        self.levels_ended = state.get("levels_ended")
        self.timings, self.init_info = state["timings"], state["init"]
        self.before = state["seconds"]
        self.emit("stage", stage="resume", level=self.level, faces=self.mesh.n_faces)
        coarse = self.viewset.at(self.config.coarse_size)
        self.appearance.restore(state.get("appearance"), coarse)
        self.appearance.decide(self.mesh, self.material, coarse, reason="resumed")
        self._choose_stiffness(coarse)

    def _load_material(self, path: Path):
        """The saved material, of the model this run's --material asks for."""
        staged = self.appearance.driver is not None
        with np.load(path) as data:
            saved_staged = "resolution" in data.files  # mesh colors
        if saved_staged != staged:
            raise InputError(self.folder.path, f"the run was made {'with' if saved_staged else 'without'} "
                             "--material staged", "resume with the options the run was started with")
        if staged:
            from ..material.model import MeshColorMaterial

            return MeshColorMaterial.load(path)
        return ConstantMaterial.load(path)

    def _choose_stiffness(self, views) -> None:
        self.stiffness = choose_stiffness(self.config, views, spatially_varying=self.appearance.driver is not None)
        self.emit("stiffness", **self.stiffness.event())

    # -- the schedule ------------------------------------------------------------------------------
    def _optimise(self) -> None:
        c = self.config
        if self.phase in ("level", "transition"):
            while True:
                if self.phase == "level":
                    record = self._run_level()
                    self.phase = "transition"
                    self._material_cycle(record)
                    self._snapshot(loss=record["loss"])
                    self.levels_ended = self._levels_end(record)
                    if self.levels_ended:
                        break
                self._transition()
                self.level += 1
                self.phase = "level"
            self.phase = "materials"
        if self.phase == "materials":
            self._finish_materials()
            self.phase = "polish"
        if self.phase == "polish":
            self._polish()
        self.appearance.settle(self.mesh, self.material, self.viewset.at(c.max_size), self.level)

    def _levels_end(self, record: dict) -> str | None:
        """Why no level follows ``record`` (None: another one does)."""
        c = self.config
        previous = self.levels[-2] if len(self.levels) > 1 else None
        if self._out_of_budget(self._geometry_reserve()):
            return "iterations" if c.iterations and self.iteration >= c.iterations else "time budget"
        if self.level + 1 >= c.max_levels:
            return "max levels"
        if not keeps_improving(previous, record, c.level_tolerance):
            return "converged"
        if self.budget.limit > c.max_faces:
            return "max faces"
        return None

    def _polish(self) -> None:
        """The paper alternates geometry and material until the loss stops improving: once the
        material stages have finished, the surface moves again under the fitted material, at
        the same face count, then the material is refined. Rounds go on while the budget lasts
        and a round lowers the validation loss by ``polish_tolerance``. The material is frozen
        during these geometry steps (noisy joint steps would blur the fitted textures).

        Measured on the paper-style dragon (Table 1 run, then one round): the levels had fitted
        the surface under the material of their short per-level cycles (validation loss 0.0050;
        0.0017 with the final material on the same mesh); the round took Chamfer 0.00215 ->
        0.00164 and held-out PSNR 28.39 -> 29.09 dB. With joint material steps instead, albedo
        RMSE went 0.048 -> 0.066."""
        c = self.config
        if self.appearance.driver is None:
            return
        while self.polished < c.polish_rounds and not self._out_of_budget(self._polish_reserve()):
            record = self._run_level(material=False)
            record["polish"] = True
            self.polished += 1
            self.appearance.refine_material()
            self._finish_materials()
            if record["loss"] > record["loss_start"] * (1 - c.polish_tolerance):
                break

    def _material_cycle(self, record: dict) -> None:
        """The effects re-checked while the lobe is off, then one stage of the staged material
        schedule, on this level's geometry and views."""
        size = level_size(self.level, self.config.coarse_size, self.config.max_size)
        views = self.viewset.at(size)
        self.appearance.recheck(self.mesh, self.material, views, self.level)
        result = self.appearance.material_cycle(self.mesh, self.material, views, self.level)
        if result is not None:
            record.setdefault("material", []).append(result)

    def _finish_materials(self, most: int = 12) -> None:
        """Once geometry has converged: material stages until their schedule ends."""
        c = self.config
        views = self.viewset.at(c.max_size)
        self.appearance.finalise()
        last = 0.0  # seconds of the last cycle: one that would end past the budget is not begun
        for _ in range(most):
            if self._out_of_budget() or (c.time_budget_s and self.elapsed() + last > c.time_budget_s):
                break
            result = self.appearance.material_cycle(self.mesh, self.material, views, self.level)
            if result is None:
                break
            last = result["seconds"]
            self.levels[-1].setdefault("material", []).append(result)
            self._snapshot(loss=result["loss"])

    def _settings(self) -> RenderSettings:
        c = self.config
        return self.appearance.geometry_settings(
            RenderSettings(spp=c.spp, max_depth=c.max_depth, integrator=c.integrator, hide_emitters=True,
                           sppc=c.spp, sppp=c.sppp, sppi=0))

    def _run_level(self, material: bool = True) -> dict:
        """One level of vertex steps, with joint material steps; or, with ``material`` False, a
        polish round: the material frozen and a steady step (see below).

        A level halves its step when the validation loss plateaus and backtracks to its best
        surface when the loss rises by ``backtrack``. Polish rounds start from a converged
        surface, where single validation losses swing by 5-15 % between evaluations while the
        held-out views keep improving (dragon, 50.6k faces, 600 steps at 1.5x the step:
        held-out PSNR 31.19 -> 31.55, 31.88, 32.19, 32.36 dB every 150 steps; the validation
        loss fell 22 % with swings of up to 13 %). There the level's rules halved the step
        within 30 steps and ended rounds after 60-260. So a round grows into its step over
        ``polish_warmup`` steps and keeps it; it backtracks only when a loss is
        ``polish_divergence`` above the best, and ends when the mean of the last
        ``polish_window`` losses stops setting new bests."""
        c = self.config
        start = time.perf_counter()
        size = level_size(self.level, c.coarse_size, c.max_size)
        views = self.viewset.at(size)
        centres = np.array([v.camera.centre for v in views])
        environment = lit_environment(self.capture, self.material)
        objective = Objective(self.mesh, self.material, views, self._settings(), environment, tone=c.tone)
        lr0 = c.step * mean_edge_length(self.mesh)
        opt = VertexOptimizer(self.mesh.vertices, self.mesh.faces, self.stiffness.lambda_, lr0)
        material_opt = Adam(c.material_lr)
        val_ids = validation_views(len(views), c.validation_views)
        val_seed = seed_for(c.seed, 10_000_019, 0)
        steady = not material
        plateau = Plateau(c.plateau_tolerance, c.polish_patience if steady else c.patience)
        full, recent = lr0, []  # a steady round's step and its validation losses
        limit = c.level_iterations * (c.polish_length if steady else 1)
        vertices = self.mesh.vertices.copy()
        plateau.update(objective.validation_loss(vertices, val_ids, val_seed, c.validation_spp))
        stage = "geometry" if material else "polish"
        self.emit("stage", stage=stage, level=self.level, faces=self.mesh.n_faces, iteration=self.iteration,
                  loss=plateau.best, size=size, seconds=round(self.elapsed(), 3),
                  environment_strength=None if environment is None else environment.strength)
        best = (vertices.copy(), self._latents())
        first_loss = plateau.best
        rng = np.random.default_rng([c.seed, self.level])
        order: list[int] = []
        warmup = self._warmup() if material and self.level == 0 else 0  # material-only steps first
        self.level_iteration = 0
        joint, frozen_at = material, None  # joint material steps, until the first backtrack
        try:
            while self.level_iteration < limit:
                self.folder.check_stop()
                if self._out_of_budget(self._geometry_reserve() if material else self._polish_reserve()):
                    break
                ids = []
                while len(ids) < min(c.views_per_step, len(views)):
                    if not order:
                        order = list(rng.permutation(len(views)))
                    ids.append(int(order.pop()))
                geometry = self.level_iteration >= warmup
                if steady:
                    opt.lr = full * min(1.0, (self.level_iteration + 1) / max(c.polish_warmup, 1))
                loss, grad, mgrads = objective.loss_and_grad(vertices, ids, seed_for(c.seed, self.iteration, 0),
                                                             geometry, joint)
                self.iteration += 1
                self.level_iteration += 1
                if not (math.isfinite(loss) and finite(*([grad] if geometry else []), *mgrads.values())):
                    self._skip("non-finite loss or gradient")
                    continue
                if geometry:
                    new_vertices = opt.step(clip_outliers(grad, self.stiffness.clip))
                    if not finite(new_vertices):
                        opt.set_vertices(vertices)
                        self._skip("non-finite vertex positions after a step")
                        continue
                    if enclosed(Mesh(new_vertices, self.mesh.faces), centres).any():
                        # no silhouette left to render from inside: the step was too long
                        opt.set_vertices(vertices)
                        opt.reset_moments()
                        opt.lr *= 0.5
                        full *= 0.5
                        self._skip("the step put a camera inside the mesh (step halved)")
                        continue
                    vertices = new_vertices
                if mgrads:
                    latents = {n: z for n, z in self._latents().items() if n in mgrads}  # the trainable ones
                    self.material.load_parameters(material_opt.step(latents, mgrads))
                self.progress.update(stage=stage, level=self.level, iteration=self.level_iteration,
                                     iterations=limit, loss=loss, faces=self.mesh.n_faces)
                if self.level_iteration % c.eval_every == 0 and steady:
                    val = objective.validation_loss(vertices, val_ids, val_seed, c.validation_spp)
                    if val > plateau.best * (1 + c.polish_divergence) or not math.isfinite(val):
                        vertices = best[0].copy()  # diverged: back to the last surface checked
                        opt.set_vertices(vertices)
                        opt.reset_moments()
                        full *= 0.5
                    else:
                        best = (vertices.copy(), best[1])
                        recent.append(val)
                        plateau.update(float(np.mean(recent[-c.polish_window:])))
                        if plateau.converged:
                            break
                elif self.level_iteration % c.eval_every == 0:
                    val = objective.validation_loss(vertices, val_ids, val_seed, c.validation_spp)
                    if plateau.update(val):
                        best = (vertices.copy(), self._latents())
                    elif val > plateau.best * (1 + c.backtrack) or not math.isfinite(val):
                        vertices = best[0].copy()  # backtrack: the step was too long
                        self.material.load_parameters(best[1])
                        opt.set_vertices(vertices)
                        opt.reset_moments()
                        if joint and geometry:
                            # the material's steps are the first suspects: Adam moves every
                            # mesh-color sample by about its step, noise or not, which undoes a
                            # fitted texture. The level goes on with the material frozen
                            joint, frozen_at = False, self.level_iteration
                        else:
                            opt.lr *= 0.5
                    settled = self.level_iteration >= c.min_level_iterations + warmup
                    if plateau.converged and settled:
                        if opt.lr <= lr0 * c.min_step_scale * 1.0001:
                            break
                        opt.lr *= 0.5
                        plateau.stale = 0
                if time.perf_counter() - self.last_snapshot >= self._snapshot_interval():
                    self.mesh = Mesh(vertices, self.mesh.faces)
                    self._snapshot(loss=loss)
        finally:
            # keep the best surface found so far, also when cancelled
            self.mesh = Mesh(best[0], self.mesh.faces)
            self.material.load_parameters(best[1])
            self._timed(stage, start)
        record = {"level": self.level, "size": size, "faces": self.mesh.n_faces, "iterations": self.level_iteration,
                  "loss_start": first_loss, "loss": plateau.best, "step_final": (full if steady else opt.lr) / lr0,
                  "material_frozen_at": frozen_at,
                  "seconds": round(time.perf_counter() - start, 3), "elapsed": round(self.elapsed(), 3)}
        if self.truth is not None and self.config.track_metrics:
            record["metrics"] = self._metrics(self.mesh)
        self.levels.append(record)
        return record

    def _warmup(self) -> int:
        """Material-only steps that open level 0 when the material is estimated: a wrong
        material makes the geometry compensate (a too-dark material inflates the mesh
        toward the lights), so the material gets a head start."""
        if not self.material.trainable:
            return 0
        cap = self.config.iterations  # a capped run keeps most of its steps for geometry
        return self.config.material_warmup if cap is None else min(self.config.material_warmup, cap // 3)

    def _latents(self) -> dict[str, np.ndarray]:
        return {n: np.array(z, np.float64) for n, z in self.material.parameters().items()}

    def _skip(self, why: str) -> None:
        self.skipped += 1
        self.emit("warning", message=f"step {self.iteration} skipped: {why} ({self.skipped} so far)")

    # -- between levels ------------------------------------------------------------------------------
    def _transition(self) -> None:
        """Re-mesh when needed, subdivide 1-to-4, honour the face budget."""
        c = self.config
        old = self.mesh
        if c.remesh != "never":
            start = time.perf_counter()
            self.emit("stage", stage="remesh", level=self.level, faces=old.n_faces)
            self.progress.update(force=True, stage="remesh", level=self.level, faces=old.n_faces)
            cameras = [v.camera for v in self.viewset.views]
            masks = [v.mask for v in self.viewset.views] if self.capture.has_masks else None
            samples = visible_samples(old, cameras, masks)
            hits = len(samples.points) + samples.back_faces + samples.outside_masks
            share = (samples.back_faces + samples.outside_masks) / max(hits, 1)
            remeshed = None
            if c.remesh == "always" or share > c.remesh_threshold:
                target = self.budget.next_target(old.n_faces)
                try:
                    remeshed = poisson_from_samples(samples, old, target, cameras=cameras, masks=masks)
                    report = inspect(remeshed)
                    if not report.closed_manifold:  # too few consistent samples (a tangled mesh): Poisson leaves holes
                        raise SurfaceReconstructionError("the rebuilt surface is not a closed manifold "
                                                         f"({', '.join(report.issues)})")
                except SurfaceReconstructionError as err:  # the current surface stays; the level goes on
                    self.emit("warning", message=f"re-meshing not applied: {err}")
                    remeshed = None
                else:
                    self.material.on_remesh(remeshed)
                    self.appearance.on_remesh(remeshed, self.material, self.viewset.at(c.coarse_size))
                    self.mesh = remeshed
            self._timed("remesh", start)
            self.levels[-1]["remesh"] = {"seconds": round(time.perf_counter() - start, 3),
                                         "inconsistent_share": round(share, 5), "back_faces": samples.back_faces,
                                         "outside_masks": samples.outside_masks, "applied": remeshed is not None,
                                         "faces": None if remeshed is None else remeshed.n_faces,
                                         "genus": None if remeshed is None else inspect(remeshed).genus}
            if remeshed is not None:
                return
        start = time.perf_counter()
        self.emit("stage", stage="refine", level=self.level, faces=old.n_faces)
        fine, _ = midpoint(old)
        self.mesh = self.budget.enforce(fine)
        if self.mesh is fine:
            self.material.on_subdivide(old, fine)
        else:
            # the simplified mesh lies on the old surface: resample the mesh colors rather than
            # restart them from grey, so the next level's steps see the fitted material. Paper-style
            # dragon, 20 min: reset 30.21 dB held-out, albedo RMSE 0.053; resampled (two runs)
            # 30.38 / 31.00 dB, 0.046 / 0.040 (README, Materials)
            self.material.on_remesh(self.mesh, old_mesh=old, reset=False)
        self._timed("refine", start)

    # -- output --------------------------------------------------------------------------------------
    def _state(self) -> dict:
        return {"vertices": self.mesh.vertices, "faces": self.mesh.faces, "level": self.level,
                "iteration": self.iteration, "phase": self.phase, "polished": self.polished,
                "budget": self.budget.state(), "levels": self.levels, "levels_ended": self.levels_ended,
                "skipped": self.skipped, "timings": self.timings,
                "init": self.init_info, "seconds": round(self.elapsed(), 3), "appearance": self.appearance.state()}

    def _snapshot_interval(self) -> float:
        """Seconds between snapshots: snapshot_every_s, stretched so that writing them (display
        mesh and resumable state, ~0.3 s at 30k faces) takes at most snapshot_share of the run."""
        c = self.config
        return max(c.snapshot_every_s, self.snapshot_seconds / c.snapshot_share if c.snapshot_share > 0 else 0.0)

    def _snapshot(self, loss) -> str:
        start = time.perf_counter()
        info = {"iteration": self.iteration, "stage": self.phase, "level": self.level,
                "faces": self.mesh.n_faces, "loss": loss}
        rel = self.folder.snapshot(self.material.display(self.mesh), info, self._state(), self.material)
        self.emit("snapshot", path=rel, iteration=self.iteration, faces=self.mesh.n_faces, loss=loss)
        self.last_snapshot = time.perf_counter()
        self.snapshot_seconds = self.last_snapshot - start
        self._timed("snapshots", start)
        return rel

    def _cancel(self) -> int:
        rel = None
        if self.mesh is not None and self.budget is not None:
            try:
                rel = self._snapshot(loss=self.levels[-1]["loss"] if self.levels else None)
            except (KeyboardInterrupt, StopRequested):  # a second request while writing: the last one stands
                rel = None
        self.emit("cancelled", snapshot=rel)
        return 130

    def _finish(self) -> None:
        self.phase = "done"
        self._snapshot(loss=self.levels[-1]["loss"] if self.levels else None)
        save_mesh(self.folder.path / "result.ply", self.mesh)
        metrics = self._metrics(self.mesh) if self.truth is not None else None
        report = {
            "capture": str(self.capture.root), "settings": dataclasses.asdict(self.config),
            "stiffness": self.stiffness.event(),
            "init": self.init_info, "levels": self.levels, "levels_ended": self.levels_ended,
            "result": {"faces": self.mesh.n_faces, "vertices": self.mesh.n_vertices,
                       "genus": inspect(self.mesh).genus, "iterations": self.iteration},
            "losses": [lv["loss"] for lv in self.levels], "skipped_steps": self.skipped,
            "timings": {**self.timings, "total": round(self.elapsed(), 3), "metrics_excluded": round(self.excluded, 3)},
            "material": self.material.summary(), "metrics": metrics,
            "premultiplied_views": self.viewset.premultiplied,
            **self.appearance.finish(self.folder.path, self.mesh, self.material),
        }
        fsio.write_json(self.folder.path / "report.json", report)
        self.emit("done", result="result.ply", report="report.json", metrics=metrics)

    def _truth(self) -> Mesh | None:
        rel = self.capture.ground_truth.get("mesh") if self.capture.ground_truth else None
        path = self.capture.path(rel) if rel else None
        return load_mesh(path) if path is not None and Path(path).is_file() else None

    def _metrics(self, mesh: Mesh) -> dict:
        """Geometry metrics against the ground truth (the default 100k samples, so every
        figure of a run compares with every other); their time is not charged to the budget."""
        from ..metrics import geometry_metrics

        start = time.perf_counter()
        out = geometry_metrics(mesh, self.truth)
        self.excluded += time.perf_counter() - start
        return {k: round(v, 6) if isinstance(v, float) else v for k, v in out.items()}
