"""Appearance between geometry levels: the staged material schedule, the fitted lighting,
the per-frame camera response and the choice of light-transport effects (the rules:
``Appearance``). Longer than 400 lines: the one place where these meet, each in a few methods."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..capture.model import Capture
from ..errors import InputError
from ..lighting.convention import AlbedoScale, check_scale, rescale_albedo, scale_report
from ..lighting.estimated_map import FILENAME as ESTIMATED_MAP
from ..lighting.estimated_map import EstimatedEnvironment
from ..lighting.summed_map import FRAME as SUMMED_FRAME, RIG_FILENAME, SummedEnvironment
from ..lighting.flash import Flash
from ..lighting.modes import ESTIMATED, MAP_FRAME
from ..material import factory
from ..material.driver import MaterialDriver
from ..material.export import write_glb
from ..material.stages import evaluate_loss
from ..render import effects
from ..render.scene import RenderSettings, SceneRenderer
from . import decision_cache, effect_costs
from .exposure_fit import ExposureFit
from .objective import Objective
from .relight import Relight
from .stiffness import STIFF


def _emitters(capture: Capture) -> list[str]:
    kinds = ["point"] if capture.has_point_lights else []
    return kinds + (["environment"] if capture.environment is not None else [])


class Appearance:
    """A run's appearance: the material and its schedule, the fitted lighting, the effects.

    - ``--material staged``: mesh-colors material (backend.material) run by its schedule, one
      stage after every geometry level and to the end once geometry has converged; re-voted
      labels and a neutral restart after every re-mesh; ``result.glb`` at the end.
    - ``--effects auto`` (default): backend.render.effects measures, on renders of the current
      estimate, which effects matter and picks the integrator, depth, shadow gradients and the
      specular lobe; re-checked after every re-mesh and when materials become spatially varying,
      and after every geometry level while the lobe is off (turned on, it restarts from neutral
      values and its constants are fitted; once on, a later measurement does not turn it off).
      ``all`` or a list forces them. Each decision is an ``effects`` event.
    - A fitted lighting (``--lighting estimate``/``flash``) gets constant-material cycles on the
      initial mesh before any geometry step (``light_first``), and restarts with the material
      once geometry has converged, to be fitted again on the final surface (``finalise``).
    - ``--exposure`` (backend.lighting.exposure): per-frame gains solved in closed form after
      every material cycle (``solve_exposure``) and divided out of the views' targets by the
      run's ViewSet (``use_views``), so the next level, cycle and validation fit them.
    - The albedo's scale (backend.lighting.convention.AlbedoScale): the mean-albedo default,
      ``--known-albedo`` or ``--map-calibrated``; ``report.json`` ``albedo_scale`` says which.
    """

    def __init__(self, capture: Capture, config, emit):
        self.capture, self.config, self.emit = capture, config, emit
        self.measure, self.overrides, self.driver = self.check(capture, config)
        self.decision: effects.EffectsDecision | None = None
        self.specular_off = False  # the diffuse-only decision took the specular lobe out of training
        self.history: list[dict] = []
        self.seconds = 0.0
        # the cost probe's verdicts: measured once per run (it costs several steps at the finer
        # levels' sizes), then applied again at every later decision
        self.costs: dict | None = None
        self.costs_from: str | None = None  # the decision that measured them
        # a new run's first cost probe runs after the first level's first steps (the run sets
        # this; ``run_pending_costs``); (probe, EffectsConfig, cache key, reason) while it waits
        self.defer_costs = False
        self.pending: tuple | None = None
        # the lighting fitted with the material: --lighting estimate's map, --lighting flash's flash
        self.lighting: EstimatedEnvironment | Flash | None = None
        self.relight = Relight()
        self.albedo_scale = AlbedoScale.from_config(config)
        if self.driver is not None and self.albedo_scale.mode == "map":
            self.driver.schedule.light_fitted = True  # the map's strength is calibrated: no factor fitted
        self.exposure: ExposureFit | None = None  # --exposure (``use_views``)

    def use_views(self, viewset) -> None:
        """The run's views; ``--exposure`` on for this capture divides their targets by the
        per-frame gains (backend.optimize.exposure_fit), solved after every material cycle."""
        self.exposure = ExposureFit.start(self.capture, self.config, viewset, self.staged,
                                          lambda message: self.emit("warning", message=message))

    def solve_exposure(self, mesh, material) -> None:
        if self.exposure is not None:
            start = time.perf_counter()
            self.exposure.solve(lambda views, settings: self._renderer(mesh, material, views, False, settings))
            self.seconds += time.perf_counter() - start

    # -- lighting ----------------------------------------------------------------------------------
    def start_lighting(self, folder, resume: bool = False) -> None:
        """``--lighting estimate``: the capture's environment becomes the fitted map (from what
        the frames show of the background, or the map a resumed run wrote to ``folder``).
        ``--lighting flash``: every frame is lit by a flash at its camera, at the intensity the
        frames suggest (a resumed run's comes back with ``restore``)."""
        if self.config.lighting in ESTIMATED:
            path, frame = folder / ESTIMATED_MAP, MAP_FRAME[self.config.lighting]
            if frame == SUMMED_FRAME:
                self.lighting = (SummedEnvironment.load(path) if resume and SummedEnvironment.files_exist(path)
                                 else SummedEnvironment.initial(self.capture, path))
            else:
                self.lighting = (EstimatedEnvironment.load(path, frame=frame) if resume and path.is_file()
                                 else EstimatedEnvironment.initial(self.capture, path, frame))
            self.capture.environment = self.lighting.environment()
        elif self.config.lighting == "flash":
            self.lighting = Flash.initial(self.capture)
        else:
            return
        if self.albedo_scale.mode == "known":
            self.lighting.albedo_scale = self.albedo_scale
        if self.driver is None:
            what = "map" if self.config.lighting in ESTIMATED else "flash intensity"
            self.emit("warning", message=f"--lighting {self.config.lighting} fits the {what} in the material "
                                         f"stages of --material staged: this run keeps the initial {what}")
        self._lighting_event("initial")

    def adopt_lighting(self, lighting, folder) -> None:
        """Continue under ``lighting``, the fitted model of ``config.lighting`` (already set to
        it) that ``--lighting auto``'s probe fitted on the run's mesh (a flash or an estimated
        map: a capture with its own lights is decided before the run). Its files are named in ``folder`` (the next snapshot
        writes them) and the provisional model's files that it does not write are removed; a
        flash lights this capture's frames, a map replaces the capture's environment."""
        folder = Path(folder)
        if isinstance(self.lighting, Flash):
            for frame in self.capture.frames:
                frame.lights[:] = []  # in place: the views hold the lists
        self.capture.environment = None
        if isinstance(lighting, Flash):
            lighting.capture = self.capture
            lighting.latent = lighting.latent  # placed in this capture's frames
        elif isinstance(lighting, SummedEnvironment):
            lighting.world.path, lighting.rig.path = folder / ESTIMATED_MAP, folder / RIG_FILENAME
        elif isinstance(lighting, EstimatedEnvironment):
            lighting.path = folder / ESTIMATED_MAP
        keep = ({ESTIMATED_MAP, RIG_FILENAME} if isinstance(lighting, SummedEnvironment)
                else {ESTIMATED_MAP} if isinstance(lighting, EstimatedEnvironment) else set())
        for name in {ESTIMATED_MAP, RIG_FILENAME} - keep:
            (folder / name).unlink(missing_ok=True)
        self.lighting = lighting
        if self.albedo_scale.mode == "known":
            lighting.albedo_scale = self.albedo_scale
        self.capture.environment = lighting.environment()
        self._lighting_event("chosen")

    def _lighting_event(self, when: str, stage: str | None = None) -> None:
        self.emit("lighting", when=when, stage=stage, **self.lighting.event())

    def write_lighting(self, folder) -> None:
        """The fitted lighting's file in ``folder`` (the map: environment.exr, atomic; with every snapshot)."""
        if self.lighting is not None:
            self.lighting.save(folder)

    def lighting_report(self) -> dict:
        if self.lighting is not None:
            out = dict(self.lighting.report(), relight=self.relight.record)
            out["scale_convention"] = self.albedo_scale.describe(self._light_word())
            return out
        return {"model": "captured", "emitters": _emitters(self.capture)}

    def _light_word(self) -> str:
        if isinstance(self.lighting, Flash):
            return "flash intensity"
        return "map" if self.lighting is not None else "map brightness factor"

    def albedo_scale_report(self, material) -> dict:
        """report.json ``albedo_scale`` (backend.lighting.convention.scale_report)."""
        return scale_report(self.albedo_scale, self._light_word(), self.lighting is not None,
                            self.capture.environment is not None, material if self.driver is not None else None)

    @staticmethod
    def check(capture: Capture, config):
        """Parse ``--effects`` and check material masks: bad input fails before any work.
        Returns (measure, overrides, material driver or None)."""
        try:
            measure, overrides = effects.parse_effects(config.effects)
        except ValueError as err:
            raise InputError(None, str(err), "write --effects auto, all, or a list such as indirect,-shadows") from None
        driver = None
        if factory.kind_for(config.material) == "meshcolors":
            # raises InputError naming the frame of a bad mask
            driver = MaterialDriver(capture, n_materials=getattr(config, "n_materials", 1))
        # "auto" (planning.lighting_choice) picks a fitted light for a capture that records none
        check_scale(config, driver is not None, config.lighting in ESTIMATED or config.lighting in ("flash", "auto"),
                    capture.environment is not None)
        return measure, overrides, driver

    # -- materials ---------------------------------------------------------------------------------
    def initial_material(self, mesh, views, given=None):
        """The material of a new run: the staged material on the initial mesh (labels voted
        on ``views``); else ``given`` (a model built by the caller) or the one --material names."""
        if self.driver is not None:
            return self.driver.material(mesh, [v.camera for v in views], [v.target for v in views],
                                        self._masks(views))
        return given if given is not None else factory.create(self.config.material)

    def load_material(self, path, folder=None):
        """The saved material of a resumed run, of the model this run's --material asks for."""
        return factory.load(path, factory.kind_for(self.config.material), folder)

    @property
    def staged(self) -> bool:
        """Whether a material schedule runs (and polish rounds with it)."""
        return self.driver is not None

    def _masks(self, views):
        return [v.mask for v in views] if all(v.mask is not None for v in views) else None

    def light_first(self, mesh, material, views) -> dict | None:
        """A fitted lighting (``--lighting estimate``/``flash``) is fitted on the initial mesh
        before any geometry step: constant-material cycles, at most ``config.light_first_cycles``,
        while the schedule stays in its constant stage (it ends that stage when a cycle stops
        improving: ``MaterialSchedule.min_improvement``). Geometry steps under a light
        that is still its first guess (a uniform map, a flash from the mean brightness) bend
        the surface to make the shading the light does not give yet, and later levels do not
        win that back (docs/notes/2026-11-28-estimated-lighting-levels.md).

        Several materials (``--materials``, material masks) get the same cycles under the
        captured lights: from the neutral grey start each paint renders too bright in the
        channels it lacks, and the geometry steps move its surface away from the lamps to
        darken it (the open corner's walls, docs/notes/2026-12-02-corner-tint.md). Returns the
        cycles' losses and time for ``report.json`` ``init``, or None when there is nothing to fit."""
        if self.driver is None or (self.lighting is None and self.driver.labels.n_materials <= 1):
            return None
        start, losses = time.perf_counter(), []
        while len(losses) < self.config.light_first_cycles and self.driver.stage == "constant":
            result = self.material_cycle(mesh, material, views, level=0)
            if result is None:
                break
            losses.append(result["loss"])
        return {"cycles": len(losses), "losses": [round(x, 8) for x in losses],
                "seconds": round(time.perf_counter() - start, 3)}

    def material_cycle(self, mesh, material, views, level: int) -> dict | None:
        """One stage of the material schedule on the current geometry."""
        if self.driver is None or self.driver.done:
            return None
        if self.driver.stage == "specular" and self.decision is not None and not self.decision.specular:
            # diffuse-only, re-checked on entering the stage: no specular lobe to texture
            self.driver.schedule.stage = "done"
            return None
        start = time.perf_counter()
        views = views if self.exposure is None else self.exposure.current(views)
        stage_before = self.driver.stage
        self.emit("stage", stage=f"material:{stage_before}", level=level, faces=mesh.n_faces)
        if self.lighting is not None:
            self.lighting.at_stage(stage_before)  # coarse to fine: the stage's map resolution
            self.capture.environment = self.lighting.environment()
        renderer = self._renderer(mesh, material, views, geometry=False)
        result = self.driver.cycle(renderer, [v.target for v in views], self._masks(views), material, self.emit,
                                   lighting=self.lighting)
        if self.lighting is not None:
            self.lighting.normalise(material)  # the scale convention; the renders do not change
            self.capture.environment = self.lighting.environment()
            self._lighting_event("fitted", stage_before)
        elif self.albedo_scale.mode == "known" and self.capture.environment is not None:
            s = self.albedo_scale.factor(material)  # the captured map's factor takes 1 / s
            rescale_albedo(material, s)
            material.light_factor /= s
        self.solve_exposure(mesh, material)
        if self.decision is not None and not self.decision.specular:
            material.disable("specular")  # the constant stage fits every channel: keep the diffuse-only model
        self.seconds += time.perf_counter() - start
        if self.driver.stage != stage_before and self.driver.stage == "specular":
            self.decide(mesh, material, views, reason="materials became spatially varying")
        return {"stage": stage_before, "loss": result.loss, "seconds": round(time.perf_counter() - start, 3)}

    def full_loss(self, mesh, material, views) -> float:
        """The material's loss over ``views`` as the schedule scores a cycle (``stages.evaluate_loss``)."""
        views = views if self.exposure is None else self.exposure.current(views)
        renderer = self._renderer(mesh, material, views, geometry=False)
        return evaluate_loss(renderer, [v.target for v in views], self._masks(views), material)

    def _last_stage(self) -> str:
        """The material schedule's last stage: diffuse when the scene has no specular lobe."""
        return "diffuse" if self.decision is not None and not self.decision.specular else "specular"

    def finalise(self, mesh=None, material=None, views=None, budget=None) -> None:
        """Geometry has converged: the material's last, longer stages follow. With a fitted
        lighting and ``config.relight_reserve`` of the time budget left (``budget``, the run's
        Budget), the lighting and the material first go back to their initial values, to be
        fitted again on the final surface (``relight.Relight``; ``judge_relight`` keeps it or
        not once the stages end)."""
        if self.driver is None or self.driver.schedule.final:
            return
        self.driver.finalise(self._last_stage())
        reserve = self.config.relight_reserve
        # a map on the camera rig (alone or summed with a world map) is not fitted afresh: every
        # view's highlights face the camera, and fresh fits there lost the views (relight.py), so
        # its reserve goes to the final stages
        if (self.lighting is not None and material is not None and reserve is not None
                and "camera" not in str(getattr(self.lighting, "frame", None))
                and not (budget is not None and budget.out(reserve))):
            self.relight.start(self, mesh, material, views)
            self._lighting_event("restarted")

    def judge_relight(self, mesh, material) -> None:
        """The final stages ended: the relit material and lighting stay, or the earlier ones
        come back (``relight.Relight.judge``; a ``lighting`` event ``relit`` or ``restored``)."""
        record = self.relight.judge(self, mesh, material)
        if record is not None:
            self._lighting_event("relit" if record["kept"] else "restored")

    def last_stage_due(self) -> bool:
        """Whether the schedule is on the final geometry and short of its last stage."""
        if self.driver is None or self.driver.done or not self.driver.schedule.final:
            return False
        stages = self.driver.schedule.STAGES
        return stages.index(self.driver.stage) < stages.index(self._last_stage())

    def hurry(self) -> None:
        """Too little time is left for the current stage and the last one: the last stage
        (which fits every channel) runs next."""
        if self.last_stage_due():
            self.driver.schedule.skip_to(self._last_stage())

    def refine_material(self) -> None:
        """The surface moved under the finished material: its last stage runs again."""
        if self.driver is not None:
            self.driver.schedule.refine(self._last_stage())

    def settle(self, mesh, material, views, level: int) -> None:
        """The run's end: a specular texture that the views left out of its fit do not support
        becomes its per-material mean (``MaterialDriver.settle``)."""
        if self.driver is None or material.channels["specular"].kind != "colors":
            return
        start = time.perf_counter()
        self.emit("stage", stage="material:check", level=level, faces=mesh.n_faces)
        renderer = self._renderer(mesh, material, views, geometry=False)
        self.driver.settle(renderer, [v.target for v in views], self._masks(views), material)
        self.seconds += time.perf_counter() - start

    def on_remesh(self, mesh, material, views) -> None:
        if self.driver is not None:
            self.driver.on_remesh(mesh, material, [v.camera for v in views], reset=False)
        self.decide(mesh, material, views, reason="re-meshed")

    def state(self) -> dict | None:
        """The material schedule's position (for --resume), or None without one."""
        if self.driver is None:
            return None
        state = self.driver.state()
        if self.lighting is not None:
            state["lighting"] = self.lighting.state()
        if self.exposure is not None:
            state["exposure"] = self.exposure.exposure.state()
        return state

    def restore(self, state: dict | None, views) -> None:
        """A resumed run: the material schedule continues where ``state`` left it."""
        if self.driver is not None:
            self.driver.restore(state, [v.target for v in views], self._masks(views))
        if self.lighting is not None and state and state.get("lighting"):
            self.lighting.restore(state["lighting"])
            self._lighting_event("resumed")
        if self.exposure is not None and state:
            self.exposure.exposure.restore(state.get("exposure"))

    def finish(self, folder, mesh, material) -> dict:
        out = {"effects": self.history, "appearance_seconds": round(self.seconds, 3),
               "lighting": self.lighting_report(), "albedo_scale": self.albedo_scale_report(material),
               "exposure": (self.exposure.exposure.report() if self.exposure is not None
                            else {"model": "off", "mode": self.config.exposure})}
        if self.driver is not None:
            write_glb(folder / "result.glb", mesh, material)
            out["material_schedule"] = self.driver.report()
        return out

    # -- effects -----------------------------------------------------------------------------------
    def decide(self, mesh, material, views, reason: str) -> None:
        """Measure (or force) the effects and announce the decision."""
        start = time.perf_counter()
        cfg = effects.EffectsConfig(max_depth_probe=max(self.config.max_depth, 4))
        found = self.decision is not None and self.decision.specular and self.measure
        # a run's first measured decision is kept beside the capture: a later run with the same
        # inputs makes it again without its probes (decision_cache)
        key = (decision_cache.key(self.capture, self.config, mesh, material, views, reason)
               if self.measure and self.decision is None else None)
        cached = None if key is None else decision_cache.load(self.capture, key)
        if cached is not None and cached[0].measured.get("costs") == "pending" and not self.defer_costs:
            cached = None  # kept by a run stopped before its cost probe: this one measures now
        if cached is not None:
            self.decision, self.costs = cached
            if self.decision.measured.get("costs") == "pending":  # its cost probe is still to run
                self.pending = self._deferred(mesh, material, views, cfg, key, reason)
        else:
            probe = [v for v in views]
            renderer = self._renderer(mesh, material, probe, geometry=False, settings=RenderSettings(spp=cfg.spp))
            cost_probe = self._cost_probe(mesh, material, views)
            # the first decision's cost probe waits for the first level's first steps (``deferred``):
            # a capture's first run then starts stepping without it
            defer = self.defer_costs and self.decision is None and self.costs is None and cost_probe is not None
            self.decision = effects.decide(
                renderer, [v.target for v in probe],
                [v.mask if v.mask is not None else np.ones(v.target.shape[:2]) for v in probe],
                _emitters(self.capture), cfg, self.overrides, self.measure, probe=None if defer else cost_probe)
            if defer and self.decision.measured.get("self_shadowing") is not None:
                self.pending = self._deferred(mesh, material, views, cfg, key, reason, cost_probe)
                if "shadows" not in self.overrides:
                    self.decision.shadows = False  # the probe's base: the cheap step until it has spoken
                self.decision.measured["costs"] = "pending"
                self.decision.reasons["shadows"] += "; off until the cost probe has run"
                if key is not None:  # a run stopped before the probe leaves the rest of the decision
                    decision_cache.store(self.capture, key, self.decision, None)
            else:
                self.pending = None  # a fresh decision took its own probe
                if key is not None:
                    decision_cache.store(self.capture, key, self.decision, self.costs)
        if found and not self.decision.specular and "specular" not in self.overrides:
            # a lobe found stays: the lighting and albedo fitted since have taken up part of the
            # highlights, which the test measures against diffuse shading under that lighting
            self.decision.specular = True
            self.decision.reasons["specular"] += "; kept on: highlights were measured earlier in the run"
        if isinstance(self.decision.measured.get("costs"), dict):
            self.costs_from = self.costs_from or reason
            self.decision.measured["costs_measured_at"] = self.costs_from
        lobe_on = self.decision.specular and self.specular_off
        if not self.decision.specular:
            self.specular_off = self.specular_off or "specular" in material.trainable
            material.disable("specular")
        elif lobe_on:  # highlights found after a diffuse-only decision: the lobe restarts
            material.restart_specular()
            self.specular_off = False
        seconds = time.perf_counter() - start
        self.seconds += seconds
        self._announce(reason, seconds)
        if lobe_on and self.driver is not None:
            fit_start = time.perf_counter()
            renderer = self._renderer(mesh, material, views, geometry=False)
            self.driver.lobe_on(renderer, [v.target for v in views], self._masks(views), material, self.emit)
            self.seconds += time.perf_counter() - fit_start

    @property
    def costs_pending(self) -> bool:
        """Whether the first decision's cost probe is still to run (``run_pending_costs``)."""
        return self.pending is not None

    def run_pending_costs(self) -> bool:
        """The first decision's cost probe, deferred past the first level's first steps: the
        same probe on the same initial mesh, views and seeds as it would have run before them
        (so the same verdicts where its timings agree), its verdicts applied to the decision,
        the decision kept in the capture's cache and announced (``effects`` event, reason
        "<reason>: cost probe"). Returns whether the geometry steps' settings changed."""
        if self.pending is None:
            return False
        probe, cfg, key, reason, material, held = self.pending
        self.pending = None
        start = time.perf_counter()
        now = {n: np.array(z, copy=True) for n, z in material.parameters().items()}
        before = self.decision.settings(RenderSettings.for_geometry(self.config), geometry=True)
        self.decision.measured.pop("costs", None)
        self.decision.reasons["shadows"] = self.decision.reasons["shadows"].replace(
            "; off until the cost probe has run", "")
        material.load_parameters(held)
        try:
            effects.weigh_costs(self.decision, probe, cfg, self.overrides)
        finally:
            material.load_parameters(now)
        seconds = time.perf_counter() - start
        self.decision.measured["seconds"] = {**self.decision.measured.get("seconds", {}), "costs": round(seconds, 3)}
        if key is not None:
            decision_cache.store(self.capture, key, self.decision, self.costs)
        self.costs_from = self.costs_from or reason
        self.decision.measured["costs_measured_at"] = self.costs_from
        self.seconds += seconds
        self._announce(f"{reason}: cost probe", seconds)
        return self.decision.settings(RenderSettings.for_geometry(self.config), geometry=True) != before

    def _deferred(self, mesh, material, views, cfg, key, reason, cost_probe=None) -> tuple:
        """What ``run_pending_costs`` needs: the probe on ``mesh`` and ``views``, and the material
        as it is now (the first steps train it; the probe measures on this one)."""
        held = {n: np.array(z, copy=True) for n, z in material.parameters().items()}
        return (cost_probe or self._cost_probe(mesh, material, views), cfg, key, reason, material, held)

    def _announce(self, reason: str, seconds: float) -> None:
        enabled = {"max_depth": self.decision.max_depth, "shadows": self.decision.shadows,
                   "specular": self.decision.specular, "silhouettes": self.decision.silhouettes,
                   "emitters": self.decision.emitters}
        record = {"reason": reason, "enabled": enabled, "measured": self.decision.measured,
                  "why": self.decision.reasons, "forced": self.decision.forced, "seconds": round(seconds, 3)}
        self.history.append(record)
        self.emit("effects", **record)

    def _cost_probe(self, mesh, material, views, n_views: int = 4):
        """The effects decision's cost probe (effects.weigh_costs): geometry steps on
        ``n_views`` spread views of ``mesh`` under each configuration, with the run's own
        sample counts, the first time; the same verdicts at later decisions. None when effects
        are not measured."""
        if not self.measure:
            return None
        if self.costs is not None:
            return lambda decision, candidates: {n: self.costs[n] for n in candidates if n in self.costs}
        c = self.config
        ids = sorted(set(np.linspace(0, len(views) - 1, min(n_views, len(views))).round().astype(int).tolist()))
        base = RenderSettings.for_geometry(c)
        objectives = {}

        def gradient(settings: RenderSettings, seed: int):
            key = (settings.integrator, settings.max_depth, settings.sppi)
            if key not in objectives:
                objectives[key] = Objective(mesh, material, views, settings, lit_environment(self.capture, material),
                                            tone=c.tone)
            return objectives[key].loss_and_grad(mesh.vertices, ids, seed, geometry=True, material=False)[1]

        def probe(decision, candidates):
            # the stiff system's smoothing as the norm: the share is that of a Large Steps direction
            self.costs = effect_costs.measure(gradient, {n: d.settings(base, geometry=True)
                                                         for n, d in candidates.items()},
                                              decision.settings(base, geometry=True), mesh.faces, mesh.n_vertices,
                                              c.lambda_ or STIFF[0])
            return self.costs

        return probe

    def level_cycle(self, mesh, material, views, level: int) -> dict | None:
        """After geometry level ``level``: the effects re-checked while the lobe is off
        (``recheck``), then one stage of the material schedule on the level's ``views``;
        the cycle's result, or None when none ran."""
        self.recheck(mesh, material, views, level)
        return self.material_cycle(mesh, material, views, level)

    def recheck(self, mesh, material, views, level: int) -> None:
        """After a geometry level, while the lobe is off: measure again. A coarse start can
        hide highlights that the refined geometry shows."""
        if (self.measure and self.decision is not None and not self.decision.specular
                and "specular" not in self.overrides):
            self.decide(mesh, material, views, reason=f"level {level}: highlights measured on the refined geometry")

    def geometry_settings(self, base: RenderSettings) -> RenderSettings:
        return base if self.decision is None else self.decision.settings(base, geometry=True)

    def material_settings(self, base: RenderSettings) -> RenderSettings:
        """What a material step renders with (the decision's effects, every bounce it keeps)."""
        return (effects.EffectsDecision() if self.decision is None else self.decision).settings(base, geometry=False)

    def _renderer(self, mesh, material, views, geometry: bool, settings: RenderSettings | None = None):
        base = settings or RenderSettings(spp=self.config.spp, max_depth=self.config.max_depth, integrator="prb")
        if self.decision is not None:
            base = self.decision.settings(base, geometry=geometry)
        return SceneRenderer(mesh, material.field, [v.camera for v in views], [v.lights for v in views],
                             lit_environment(self.capture, material), base)


def lit_environment(capture: Capture, material):
    """The capture's environment at the brightness the material was fitted under: the
    staged material's light factor k (scene scale = strength x k) applies to every render of
    the capture's own lighting."""
    env = capture.environment
    factor = material.light_factor
    return env if env is None or factor == 1.0 else env.scaled(factor)


def _disable_specular(material) -> None:
    """The diffuse-only model: specular fixed at 0 and no longer trained (Material.disable)."""
    material.disable("specular")
