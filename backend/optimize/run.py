"""``reconstruct()``: the one entry point of a reconstruction (the ``reconstruct`` command's
job, the benchmarks' children and the stability suite all call it). A run initialises a mesh
and a material, then goes through ``Reconstruction.PHASES`` in order; ``RunState`` says where
it stands (for --resume and report.json), ``Budget`` holds the clock and its limits.

Longer than 400 lines: the phases, the snapshots and the report share one run's state, and
each phase's work lives in its own module; what is left here is their order."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from .. import fsio, interrupt
from ..capture.model import Capture
from ..geometry.init import cached_initial_mesh, check_lights_outside
from ..geometry.mesh import Mesh, load_mesh, save_mesh
from ..geometry.simplify import FaceBudget
from ..geometry.topology import inspect
from ..metrics import geometry_metrics
from ..render.scene import RenderSettings
from .appearance import Appearance, lit_environment
from .budget import Budget
from .camera_fit import CameraRefinement
from .config import ReconstructConfig
from .convergence import level_size, levels_end, next_level
from .levels import Fit, LevelRun, PolishRun
from .objective import Objective
from .progress import LockedEmitter, Paced, Progress, StopOnProgress
from .records import LevelRecord, RunState
from .run_folder import Result, RunFolder, StopRequested, snapshot_interval
from .stiffness import choose as choose_stiffness
from .texture_stage import TextureStage
from .transition import transition
from .views import ViewSet

# a cycle of the last material stage costs about this many cycles of an earlier one (it
# fits specular and roughness textures besides the albedo)
LAST_STAGE_COST = 1.5
# a new run's first cost probe (the effects decision's shadow-gradient and extra-bounce
# verdicts) runs after this many geometry steps of the first level, which take the cheap
# settings (no shadow gradients, the measured depth): the first step comes without it
COST_PROBE_AFTER = 1


def reconstruct(capture: Capture, out: RunFolder, config: ReconstructConfig, events, *, resume: bool = False,
                material=None, objective_factory=Objective, planner=None, tracking=None,
                remaining=None, started: float | None = None, level_limit: int | None = None,
                lighting_choice: dict | None = None, initial: tuple | None = None, lighting_probe=None) -> Result:
    """Reconstruct ``capture`` into the run folder ``out`` (docs/protocol.md), emitting
    ``events`` (an Emitter: ``events(name, **fields)``). Args:
        resume: continue from the folder's saved state.
        material: the material model of a new run (default: the one ``config.material``
            names, through material.factory; a staged run always builds its own).
        objective_factory: builds each level's objective, called as ``Objective`` is (tests
            wrap the real one to record every step).
        planner: called as ``planner(capture, viewset, geometry_settings, material_settings,
            mesh, held)`` once, when a new run's first level and its material cycle have
            ended (so the first step comes without delay), charged to the budget. Returns
            None or the live estimate of the time left, which the progress events follow
            (``observe(event, fields, now)`` and ``seconds(now)``, as
            planning.remaining.Remaining has).
        tracking: ``tracking(capture, config)`` -> (the capture to fit, its held-out accuracy
            tracker): planning.tracking.start, which ``config.track_accuracy`` needs.
        remaining: a resumed run's live estimate of the time left (planning.remaining.resumed).
        started: the ``time.perf_counter()`` reading the budget's clock starts from (the
            command's start; default: now).
        level_limit: the geometry steps after which a level ends (None: ``level_iterations``).
        lighting_choice: ``--lighting auto``'s probe (planning.lighting_choice), written to
            report.json ``lighting_choice``.
        initial: a new run's initial mesh and its kind, as ``geometry.init.initial_mesh`` makes
            them from the frames the run fits (the lighting probe made it); None: made here.
        lighting_probe: ``--lighting auto``'s choice after the first level
            (planning.lighting_choice.Deferred: ``choose(capture, mesh, level, emit)`` ->
            (choice, the winner's fitted lighting), ``announce(emit, choice)``); the run starts
            under ``config.lighting`` (its provisional lighting), and when the first level it
            runs has ended (with its material cycle and camera refinement) the probe runs on
            that level's mesh; a different winner replaces the lighting (``config.lighting`` and
            the fitted model, ``Appearance.adopt_lighting``) and one material cycle re-fits the
            material under it, before the level's snapshot; the event follows the snapshot.
    Raises InputError on bad input; cancellation returns exit code 130."""
    if tracking is None:
        if config.track_accuracy:
            raise ValueError("config.track_accuracy needs tracking= (backend.planning.tracking.start)")
        tracking = lambda capture, config: (capture, Untracked())  # noqa: E731
    run = Reconstruction(capture, out, config, events, tracking, material=material, resume=resume,
                         objective_factory=objective_factory, started=started, level_limit=level_limit)
    run.lighting_choice, run.initial, run.lighting_probe = lighting_choice, initial, lighting_probe
    return Result(run.run(planner, remaining), out.path)


class Untracked:
    """The tracker of a run that scores no held-out views (``reconstruct`` without ``tracking``)."""

    enabled, held, clock = False, None, None

    def observe(self, emit):
        return emit

    def due(self) -> bool:
        return False

    def state(self) -> None:
        return None

    def restore(self, state) -> None:
        pass

    def report(self) -> None:
        return None


class Reconstruction:
    """One run: its phases (``PHASES``), snapshots and report (see ``reconstruct``)."""

    # (method, the RunState phases it runs from, the phase after it), in the order a run goes
    # through them; a resumed run starts at its state's phase
    PHASES = (("_levels", ("level", "transition"), "materials"),
              ("_finish_materials", ("materials",), "polish"),
              ("_polish", ("polish",), "polish"))

    def __init__(self, capture: Capture, folder: RunFolder, config: ReconstructConfig, emit, tracking,
                 material=None, resume: bool = False, objective_factory=Objective, started: float | None = None,
                 level_limit: int | None = None):
        capture, self.accuracy = tracking(capture, config)  # --track-accuracy: views held out of every fit
        self.capture, self.folder, self.config = capture, folder, config
        self.state = RunState()
        self.paced = Paced(emit)
        emit = self.accuracy.observe(StopOnProgress(self.paced, folder.check_stop,
                                                    lambda: self.state.phase != "done"))
        self.emit = LockedEmitter(emit)
        if self.accuracy.held is not None and self.accuracy.held.note:
            self.emit("warning", message=self.accuracy.held.note)
        self.material = material
        self.resume = resume
        self.objective_factory = objective_factory
        self.viewset = ViewSet(capture, config.max_size)
        self.appearance = Appearance(capture, config, emit)
        self.appearance.use_views(self.viewset)  # --exposure: the per-frame gains divide its targets
        self.appearance.start_lighting(folder.path, resume)
        self.budget = self.paced.budget = Budget(config, self.state, staged=self.appearance.staged, started=started)
        self.texture = TextureStage(capture, config, self.appearance.staged)
        self.budget.texture_share = self.texture.reserve_share()
        self.level_limit = level_limit
        self.planner = None  # called once after the first level (``reconstruct``)
        self.accuracy.clock = self.budget.elapsed
        self.validation: float | None = None  # the last validation loss a level computed
        self.truth = truth_mesh(capture)
        self.last_snapshot = 0.0
        self.snapshot_seconds = 0.0  # what the last snapshot took to write
        self.stiffness = None
        self.cameras = CameraRefinement.start(capture, config, self.viewset)  # --refine-cameras
        self.lighting_choice = self.initial = None  # --lighting auto's probe and its (mesh, kind): ``reconstruct``
        self.lighting_probe = None  # --lighting auto's choice after the first level (``reconstruct``)

    def run(self, planner=None, remaining=None) -> int:
        """Run to the end (``planner``, ``remaining``: as ``reconstruct`` takes them); returns
        the exit code (0 done, 130 cancelled)."""
        with Progress(self.emit, self.budget.fraction, self.budget.elapsed) as self.paced.progress:
            try:
                if self.resume:
                    self._load_state(remaining)
                else:
                    self.planner = planner
                    self._start()
                self.track("resume" if self.resume else "start")
                self._phases()
            except (KeyboardInterrupt, StopRequested):
                return self._cancel()
            except Exception as err:
                if not interrupt.is_cancel(err):
                    raise
                return self._cancel()
            self._finish()
        return 0

    # -- start -------------------------------------------------------------------------------------
    def _start(self) -> None:
        c, s = self.config, self.state
        start = time.perf_counter()
        self.emit("stage", stage="init", level=0, faces=0)
        self.paced.progress.update(force=True, stage="init", level=0, iteration=0, iterations=0, loss=None, faces=0)
        s.mesh, kind = self.initial or cached_initial_mesh(self.capture, c.init, c.initial_faces,
                                                           warn=lambda message: self.emit("warning", message=message))
        check_lights_outside(self.capture, s.mesh, kind)
        coarse = self.viewset.at(c.coarse_size)
        self.material = self.appearance.initial_material(s.mesh, coarse, given=self.material)
        s.material_kind = self.material.KIND
        lit = self.appearance.light_first(s.mesh, self.material, coarse)
        self.appearance.defer_costs = True
        self.appearance.decide(s.mesh, self.material, coarse, reason="initial mesh")
        self.stiffness = choose_stiffness(self.config, coarse, spatially_varying=self.appearance.staged)
        self.emit("stiffness", **self.stiffness.event())
        s.budget = FaceBudget(s.mesh.n_faces, growth=c.face_growth)
        s.level_limit = self.level_limit
        s.timed("init", start)
        report = inspect(s.mesh)
        s.init = {"kind": kind, "faces": s.mesh.n_faces, "genus": report.genus,
                  "seconds": round(time.perf_counter() - start, 3)}
        if self.truth is not None:
            s.init["metrics"] = self.metrics(s.mesh)
        if lit is not None:
            s.init["light_first"] = lit
        self.snapshot(loss=None)

    def _load_state(self, remaining) -> None:
        saved, material_path = self.folder.load_state()
        s = self.state = self.budget.state = RunState.from_json(saved)
        self.accuracy.restore(s.accuracy)
        self.material = self.appearance.load_material(material_path, self.folder.path)
        s.material_kind = self.material.KIND
        self.budget.remaining = remaining  # its plan, phases done
        self.emit("stage", stage="resume", level=s.level, faces=s.mesh.n_faces)
        coarse = self.viewset.at(self.config.coarse_size)
        self.cameras.restore(s.cameras)
        self.appearance.restore(s.appearance, coarse)
        self.appearance.decide(s.mesh, self.material, coarse, reason="resumed")
        self.stiffness = choose_stiffness(self.config, coarse, spatially_varying=self.appearance.staged)
        self.emit("stiffness", **self.stiffness.event())

    # -- the phases --------------------------------------------------------------------------------
    def _phases(self) -> None:
        s = self.state
        for method, phases, after in self.PHASES:
            if s.phase in phases:
                getattr(self, method)()
                s.phase = after
        self.appearance.settle(s.mesh, self.material, self.viewset.at(self.config.max_size), s.level)
        self.texture.run(s.mesh, self.material, self.appearance, self.budget, self.emit, s.level)

    def _levels(self) -> None:
        """Geometry levels, each followed by a material cycle and a snapshot, with a transition
        (re-mesh or subdivide) between two, until ``levels_end`` gives a reason."""
        s = self.state
        while True:
            if s.phase == "level":
                record = self._level(LevelRun)
                s.phase = "transition"
                self.track("level")
                views = self.viewset.at(level_size(s.level, self.config.coarse_size, self.config.max_size))
                cycle = self.appearance.level_cycle(s.mesh, self.material, views, s.level)
                if cycle is not None:
                    record.add_cycle(cycle)
                    self.track("material")
                self.cameras.after_level(s, self.material, views, self._fit().settings,  # --refine-cameras
                                         lit_environment(self.capture, self.material), self.budget, self.emit,
                                         self.folder.check_stop)
                probe, self.lighting_probe = self.lighting_probe, None
                choice = None if probe is None else self._choose_lighting(probe, record, views)
                self.snapshot(loss=record.loss)
                if choice is not None:
                    probe.announce(self.emit, choice)
                self._plan()
                s.levels_ended = levels_end(self.config, s, self.budget, record)
                if s.levels_ended:
                    return
            transition(self._fit(), self.appearance)
            s.level += 1
            s.phase = "level"

    def _choose_lighting(self, probe, record: LevelRecord, views) -> dict:
        """``--lighting auto`` after the first level: the probe on its mesh (``reconstruct``'s
        ``lighting_probe``); under a different winner, its fitted lighting and one material
        cycle on ``views``. Returns report.json ``lighting_choice``."""
        s, start = self.state, time.perf_counter()
        provisional = self.config.lighting
        choice, lighting = probe.choose(self.capture, s.mesh, s.level, self.emit)
        winner = choice["winner"]
        if winner != provisional:
            self.config.lighting = winner  # the config the run and its parts share
            self.appearance.adopt_lighting(lighting, self.folder.path)
            cycle = self.appearance.material_cycle(s.mesh, self.material, views, s.level)
            if cycle is not None:
                record.add_cycle(cycle)
                self.track("material")
        choice["switched"] = winner != provisional
        choice["seconds_in_run"] = round(time.perf_counter() - start, 3)
        self.lighting_choice = choice
        s.timed("lighting_choice", start)
        return choice

    def _plan(self) -> None:
        """The planner's estimate of the time left, once, after the first level: measuring this
        capture's step costs before the first step would delay it (``reconstruct``)."""
        planner, self.planner = self.planner, None
        if planner is None:
            return
        start, c = time.perf_counter(), self.config
        self.budget.remaining = planner(
            self.capture, self.viewset, self.appearance.geometry_settings(RenderSettings.for_geometry(c)),
            self.appearance.material_settings(RenderSettings.for_geometry(c)), self.state.mesh, self.accuracy.held)
        self.state.timed("plan", start)

    def _level(self, kind: type[LevelRun]) -> LevelRecord:
        """One level or polish round (``kind``) on the current state; its record."""
        level = kind(self._fit())
        try:
            record = level()
        finally:
            self.validation = level.validation
        if self.truth is not None and self.config.track_metrics:
            record.metrics = self.metrics(self.state.mesh)
        return record

    def _fit(self) -> Fit:
        return Fit(self.capture, self.config, self.state, self.viewset, self.material, self.budget, self.stiffness,
                   self.appearance.geometry_settings(RenderSettings.for_geometry(self.config)), self.emit, self.paced.progress, self.folder.check_stop, self._checkpoint,
                   self.objective_factory, self._after_step)

    def _after_step(self, geometry_steps: int) -> RenderSettings | None:
        """After the first level's ``COST_PROBE_AFTER``-th geometry step: the first decision's
        deferred cost probe; the geometry settings that follow it when they changed."""
        if not self.appearance.costs_pending or geometry_steps < COST_PROBE_AFTER:
            return None
        start = time.perf_counter()
        changed = self.appearance.run_pending_costs()
        self.state.timed("effects", start)
        return self.appearance.geometry_settings(RenderSettings.for_geometry(self.config)) if changed else None

    def _checkpoint(self, vertices, loss: float, validation: float | None) -> None:
        """Inside a level: a snapshot every ``snapshot_interval`` and the held-out views scored
        every ``accuracy_every_s`` (--track-accuracy)."""
        s = self.state
        self.validation = validation
        if time.perf_counter() - self.last_snapshot >= snapshot_interval(self.config, self.snapshot_seconds):
            s.mesh = Mesh(vertices, s.mesh.faces)
            self.snapshot(loss=loss)
        if self.accuracy.due():
            self.track("every", Mesh(vertices, s.mesh.faces))

    def _polish(self) -> None:
        """Alternate geometry and material until the loss stops improving (as the paper does):
        once the material stages have finished, the surface moves again under the fitted
        material at the same face count (``PolishRun``), then the material is refined. Rounds
        go on while the budget lasts and a round lowers the validation loss by
        ``polish_tolerance``."""
        c, s = self.config, self.state
        if not self.appearance.staged:
            return
        while s.polished < c.polish_rounds and not self.budget.out(self.budget.polish_reserve()):
            record = self._level(PolishRun)
            s.polished += 1
            self.track("polish")
            self.appearance.refine_material()
            self._finish_materials()
            if record.loss > record.loss_start * (1 - c.polish_tolerance):
                break

    def _finish_materials(self) -> None:
        """Once geometry has converged: material stages until their schedule ends, at most
        ``config.final_material_cycles`` cycles."""
        s, most = self.state, self.config.final_material_cycles
        views = self.viewset.at(self.config.max_size)
        self.texture.size_reserve(s.mesh, self.material, self.appearance, self.budget)
        self.appearance.finalise(s.mesh, self.material, views, self.budget)
        last = 0.0  # seconds of the last cycle: one that would end past the budget is not begun
        for _ in range(most):
            if self.budget.out() or not self.budget.fits(last):
                break
            # the last stage (specular: every channel, highlights included) must have its turn:
            # an earlier stage begins only when this cycle and one of the last stage both fit
            if self.appearance.last_stage_due() and not self.budget.fits(last * (1 + LAST_STAGE_COST)):
                self.appearance.hurry()
            result = self.appearance.material_cycle(s.mesh, self.material, views, s.level)
            if result is None:
                break
            last = result["seconds"]
            s.levels[-1].add_cycle(result)
            self.track("material")
            self.snapshot(loss=result["loss"])
        self.appearance.judge_relight(s.mesh, self.material)

    def track(self, why: str, mesh: Mesh | None = None) -> None:
        """Score the held-out views (--track-accuracy; planning/tracking.py) with ``mesh`` (default
        the state's) and the current material: ``why`` "every" only when the interval has passed,
        else at a boundary (start, level, material, polish, end). Charged to the budget."""
        if not self.accuracy.enabled or (why == "every" and not self.accuracy.due()):
            return
        s = self.state
        start = time.perf_counter()
        point = self.accuracy.score(s.mesh if mesh is None else mesh, self.material, self.appearance.lighting,
                                    level=s.level, phase=s.phase, why=why, validation_loss=self.validation,
                                    folder=self.folder.path)
        s.timed("accuracy", start)
        self.emit("accuracy", **point)

    def metrics(self, mesh: Mesh) -> dict:
        """Geometry metrics against the ground truth (the default 100k samples, so every
        figure of a run compares with every other); charged to the budget, which holds the
        last scoring's seconds back for the one at the end."""
        start = time.perf_counter()
        out = geometry_metrics(mesh, self.truth)
        self.budget.metrics_s = time.perf_counter() - start
        return {k: round(v, 6) if isinstance(v, float) else v for k, v in out.items()}

    # -- output --------------------------------------------------------------------------------------
    def snapshot(self, loss) -> str:
        s = self.state
        start = time.perf_counter()
        info = {"iteration": s.iteration, "stage": s.phase, "level": s.level, "faces": s.mesh.n_faces, "loss": loss}
        s.accuracy = self.accuracy.state()
        s.cameras = self.cameras.state()
        state = s.to_json(self.budget.elapsed(), self.appearance.state())
        self.appearance.write_lighting(self.folder.path)  # before the snapshot that announces it
        rel = self.folder.snapshot(self.material.display(s.mesh), info, state, self.material)
        self.emit("snapshot", path=rel, iteration=s.iteration, faces=s.mesh.n_faces, loss=loss)
        self.last_snapshot = time.perf_counter()
        self.snapshot_seconds = self.budget.snapshot_s = self.last_snapshot - start
        s.timed("snapshots", start)
        return rel

    def _cancel(self) -> int:
        rel = None
        if self.state.mesh is not None and self.state.budget is not None:
            try:
                self.appearance.judge_relight(self.state.mesh, self.material)  # a relight under way
                rel = self.snapshot(loss=self.state.last_loss)
            except (KeyboardInterrupt, StopRequested):  # a second request while writing: the last one stands
                rel = None
        self.emit("cancelled", snapshot=rel)
        return 130

    def _finish(self) -> None:
        s = self.state
        s.phase = "done"
        self.track("end")
        self.snapshot(loss=s.last_loss)
        save_mesh(self.folder.path / "result.ply", s.mesh)
        metrics = self.metrics(s.mesh) if self.truth is not None else None
        tracked = self.accuracy.report()
        c = self.config
        expected = next_level(s.levels, s.levels_ended, (tracked or {}).get("level_gains", []),
                              level_size(s.level + 1, c.coarse_size, c.max_size))
        report = {
            "capture": str(self.capture.root), "settings": dataclasses.asdict(self.config),
            "stiffness": self.stiffness.event(),
            "init": s.init, "levels": [lv.to_json() for lv in s.levels], "levels_ended": s.levels_ended,
            "level_limit": s.level_limit or c.level_iterations,
            "result": {"faces": s.mesh.n_faces, "vertices": s.mesh.n_vertices,
                       "genus": inspect(s.mesh).genus, "iterations": s.iteration},
            "losses": [lv.loss for lv in s.levels], "skipped_steps": s.skipped,
            "timings": {**s.timings, "total": round(self.budget.elapsed(), 3)},
            "material": self.material.summary(), "metrics": metrics,
            "premultiplied_views": self.viewset.premultiplied,
            "accuracy_time": tracked, "next_level": expected, "texture_stage": self.texture.report(s.levels),
            **self.appearance.finish(self.folder.path, s.mesh, self.material),
            "cameras_refined": self.cameras.finish(self.folder.path, s.mesh, self.accuracy.held is not None),
        }
        if self.lighting_choice is not None:
            report["lighting_choice"] = self.lighting_choice
        fsio.write_json(self.folder.path / "report.json", report)
        self.emit("done", result="result.ply", report="report.json", metrics=metrics, next_level=expected)



def truth_mesh(capture: Capture) -> Mesh | None:
    """The capture's ground-truth mesh, when it names one that exists."""
    rel = capture.ground_truth.get("mesh") if capture.ground_truth else None
    path = capture.path(rel) if rel else None
    return load_mesh(path) if path is not None and Path(path).is_file() else None

