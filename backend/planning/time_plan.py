"""The plan: what each quality preset will cost on *this* capture, before the run; a
preset's time is its steps times this capture's measured step costs (planning/step_costs.py)
plus a fixed part (the model: ``predict``)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..geometry.simplify import FaceBudget
from ..optimize.convergence import level_size
from ..optimize.views import ViewSet, validation_views
from ..render import effects
from ..render.scene import RenderSettings
from .accuracy_forecast import extrapolated, gain, load_gains, predicted_psnr
from .remaining import Phase
from .step_costs import MAX_PROBE_FACES, Point, StepCosts, cached, fit, measure, pixels_for, probe_mesh  # noqa: F401 (the plan's API)

FIXED_SECONDS = 15.0  # process start, loading, initial mesh, effects decision, snapshots, outputs
# means over staged Draft runs (docs/results.md): these end on their own
# convergence, so runs differ, and they are the main source of the plan's error
FINAL_MATERIAL_CYCLES = 4.5  # long cycles (x4 iterations) on the converged geometry before polishing
POLISH_ROUNDS = 2.5  # each followed by one long refinement cycle
POLISH_STEPS = 170  # steps per polish round (at most level_iterations x polish_length)
MATERIAL_ITERATIONS = 40  # FitSettings.iterations
LEVEL_SLACK = 1.25  # a calibrated level may run this much longer than planned before it ends
# a material iteration's own work beyond render and gradient (Adam, smoothness, highlight weights)
MATERIAL_OVERHEAD_S = 0.03


# -- the levels a preset goes through ------------------------------------------------------------------
@dataclass
class LevelPlan:
    level: int
    size: int
    faces: int
    steps: int
    seconds: float = 0.0

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "seconds": round(self.seconds, 1)}


def levels(config, entry: dict | None = None) -> tuple[list[LevelPlan], str]:
    """The levels (size, faces, steps) a run of ``config`` goes through, and where the step
    counts come from: the calibration ``entry`` of its preset (levels and iterations of the
    calibration run) or the config's own limits."""
    c = config
    n, per_level = c.max_levels, c.level_iterations
    source = "config: max_levels x level_iterations"
    if entry and entry.get("levels") and entry.get("iterations"):
        n = min(int(entry["levels"]), c.max_levels)
        per_level = min(c.level_iterations, max(c.min_level_iterations, round(entry["iterations"] / entry["levels"])))
        source = "calibration run: its levels and steps per level"
    budget = FaceBudget(c.initial_faces, growth=c.face_growth)
    faces, out, total = c.initial_faces, [], 0
    for level in range(n):
        steps = per_level if c.iterations is None else max(0, min(per_level, c.iterations - total))
        if steps == 0:
            break
        out.append(LevelPlan(level, level_size(level, c.coarse_size, c.max_size), faces, steps))
        total += steps
        if budget.limit > c.max_faces:
            break
        faces = budget.next_target(faces)  # subdivided 1-to-4, simplified to the budget (which then grows)
    return out, source


# -- what a preset costs ---------------------------------------------------------------------------------
@dataclass
class PresetPlan:
    preset: str
    levels: list[LevelPlan]
    steps_from: str
    geometry_s: float
    material_s: float
    polish_s: float
    fixed_s: float
    budget_s: float | None = None
    level_limit: int | None = None  # steps after which a level ends (calibrated steps only)
    expected_f1: float | None = None  # on the calibration scene
    predicted_psnr: float | None = None  # held-out, from this capture's probe (planning/accuracy_forecast.py)
    psnr_spread: float | None = None  # the calibration captures' largest distance from their median gain
    psnr_extrapolated: str | None = None  # "finer"/"coarser": scored at a size no calibration capture was
    phases: list[Phase] = dataclasses.field(default_factory=list)  # in order, for planning/remaining.py

    @property
    def unbounded_seconds(self) -> float:
        return self.geometry_s + self.material_s + self.polish_s + self.fixed_s

    @property
    def capped(self) -> bool:
        """Whether the time budget ends the run before its levels do."""
        return bool(self.budget_s and self.unbounded_seconds > self.budget_s)

    @property
    def seconds(self) -> float:
        return min(self.unbounded_seconds, self.budget_s) if self.capped else self.unbounded_seconds

    @property
    def minutes(self) -> float:
        return self.seconds / 60.0

    def psnr_text(self) -> str | None:
        """'≈ 24 ± 2 dB'; '21+ dB' for a capture scored finer than the calibration's (a floor:
        planning/accuracy_forecast.py); None without a prediction."""
        return psnr_text(self.predicted_psnr, self.psnr_spread, self.psnr_extrapolated)

    def to_json(self) -> dict:
        return {"preset": self.preset, "predicted_minutes": round(self.minutes, 2), "capped_by_budget": self.capped,
                "unbounded_minutes": round(self.unbounded_seconds / 60, 2),
                "geometry_s": round(self.geometry_s, 1), "material_s": round(self.material_s, 1),
                "polish_s": round(self.polish_s, 1), "fixed_s": round(self.fixed_s, 1),
                "levels": [lv.to_json() for lv in self.levels], "steps_from": self.steps_from,
                "level_limit": self.level_limit,
                "expected_f1": self.expected_f1, "predicted_psnr": self.predicted_psnr, "psnr_spread": self.psnr_spread,
                "psnr_extrapolated": self.psnr_extrapolated,
                "phases": [p.to_json() for p in self.phases]}


def predict(name: str, config, costs: StepCosts, pixels_at, n_views: int, staged: bool,
            entry: dict | None = None) -> PresetPlan:
    """The predicted time of ``config`` on the capture whose steps ``costs`` measured
    (``pixels_at(size)``: one view's pixels at a level size).

    Model. A run's time is its steps times what a step costs on this capture, plus a fixed part:

        step(size, faces) = k * g(p, f) + (2 V / eval_every) * r(p, f)
        g, r, m(p, f)     = a + b * p + c * f      (least squares over the measured points, each >= 0)

    ``g`` is one view's share of a two-view forward+backward geometry step
    (``Objective.loss_and_grad``; the per-call overhead is shared as in a run's step), ``r`` one
    view's forward render at half the validation samples (a validation loss renders each of its
    V views twice every ``eval_every`` steps), ``m`` one view's material-only gradient step;
    ``p`` is the pixels of one view at the level's size (the capture's aspect, capped at its
    resolution), ``f`` the faces, ``k`` the preset's views per step. They are timed on this
    capture (cameras, lights, image sizes) with the run's render settings, after an untimed step
    that compiles the kernels, on the run's initial mesh split to the largest face count the
    levels reach (``probe_mesh``; icospheres for ``--plan``), at the smallest and the largest
    image size: four points, three coefficients.

    A preset's levels follow its settings: level l renders at ``level_size(l)`` with the faces
    the face budget gives after l subdivisions (``FaceBudget``); ``levels`` and ``steps`` per
    level are the calibration run's (``presets.json``), else ``max_levels`` x ``level_iterations``.
    A level ends on its own convergence; one whose validation loss keeps creeping down (mesh
    colors fitted jointly on a textured object) would run to ``level_iterations``, so a run that
    follows a calibrated plan stops each level at ``LEVEL_SLACK`` times the planned steps
    (``PresetPlan.level_limit``; the later levels, the final stages and the polish get the time).
    With the staged material (the default) every level is followed by one material cycle of
    ``FitSettings.iterations`` one-view steps and a full-view evaluation, geometry convergence by
    ``FINAL_MATERIAL_CYCLES`` (at most ``final_material_cycles``) cycles four times as long, and ``POLISH_ROUNDS`` (at most
    ``polish_rounds``) polish rounds of ``POLISH_STEPS`` steps, each with a refinement cycle (not
    when an iteration cap ends the run with its levels). A
    fitted lighting (``estimate``, ``flash``) or several materials (``n_materials``) add
    ``light_first_cycles`` cycles before level 0.
    ``FIXED_SECONDS`` covers start, loading, initialisation and the effects decision. A time
    budget or an iteration cap cuts the prediction where the run would stop.

    A run plans its ``preset`` event with the effects it decided (``reconstruct``'s planner);
    ``--plan`` decides nothing and times the likely settings (``geometry_settings``). Shadow
    gradients are charged at the samples a level keeps (``optimize.shadow_samples``). Step counts
    come from the calibration scene lit as the capture is; a re-mesh is left out. Each preset's
    held-out PSNR comes from planning/accuracy_forecast.py. ``bench plan`` compares predicted and measured
    (docs/results.md).
    """
    c = config
    plan, source = levels(c, entry)
    limit = level_limit(c, entry)
    val = len(validation_views(n_views, c.validation_views))
    geometry = material = 0.0
    phases = []
    long_units = 4 * MATERIAL_ITERATIONS
    for lv in plan:
        p = pixels_at(lv.size)
        step = c.views_per_step * costs("gradient", p, lv.faces) + 2 * val * costs("forward", p, lv.faces) / c.eval_every
        lv.seconds = lv.steps * step + 2 * val * costs("forward", p, lv.faces)
        geometry += lv.seconds
        phases.append(Phase("level", lv.steps, lv.seconds / lv.steps, cap=limit or c.level_iterations))
        if staged:
            cycle = cycle_seconds(costs, p, lv.faces, n_views)
            material += cycle
            phases.append(Phase("cycle", MATERIAL_ITERATIONS, cycle / MATERIAL_ITERATIONS))
    polish = 0.0
    count = getattr(c, "n_materials", 1)  # material masks are not seen here
    several = isinstance(count, int) and count > 1
    if staged and plan and (c.lighting in ("estimate", "rig", "world+rig", "flash") or several):  # constants first, initial mesh
        material += c.light_first_cycles * cycle_seconds(costs, pixels_at(plan[0].size), plan[0].faces, n_views)
    cap_ends = c.iterations is not None and sum(lv.steps for lv in plan) >= c.iterations
    if staged and plan and not cap_ends:  # an iteration cap ends a run with its levels' cycles
        last = plan[-1]
        p = pixels_at(c.max_size)
        long_cycle = cycle_seconds(costs, p, last.faces, n_views, scale=4)
        finals = min(FINAL_MATERIAL_CYCLES, c.final_material_cycles)
        material += finals * long_cycle
        phases.append(Phase("final", long_units, long_cycle / long_units, count=finals))
        step = c.views_per_step * costs("gradient", p, last.faces) + 2 * val * costs("forward", p, last.faces) / c.eval_every
        steps = min(POLISH_STEPS, c.level_iterations * c.polish_length)
        rounds = min(POLISH_ROUNDS, c.polish_rounds)
        polish = rounds * (steps * step + long_cycle)
        if rounds > 0:
            phases.append(Phase("polish", steps, step, cap=c.level_iterations * c.polish_length, count=rounds,
                                cycle_units=long_units, cycle_s=long_cycle / long_units))
    return PresetPlan(name, plan, source, geometry, material, polish, FIXED_SECONDS, c.time_budget_s,
                      limit, (entry or {}).get("expected_f1"), phases=phases)


def level_limit(config, entry: dict | None) -> int | None:
    """The steps after which a level of a run that follows the calibration ``entry`` ends:
    ``LEVEL_SLACK`` x its steps per level, within [min_level_iterations, level_iterations];
    None without a calibration (the config's own limits hold)."""
    if not (entry and entry.get("levels") and entry.get("iterations")):
        return None
    c = config
    per_level = entry["iterations"] / entry["levels"]
    return int(min(c.level_iterations, max(c.min_level_iterations, math.ceil(LEVEL_SLACK * per_level))))


def cycle_seconds(costs: StepCosts, pixels: float, faces: int, n_views: int, scale: int = 1) -> float:
    """One material cycle: its one-view material steps (each with the fit's own work on the
    mesh colors, MATERIAL_OVERHEAD_S) and a full-view evaluation."""
    step = costs("material", pixels, faces) + MATERIAL_OVERHEAD_S
    return scale * MATERIAL_ITERATIONS * step + n_views * costs("forward", pixels, faces)


# -- measuring ------------------------------------------------------------------------------------------
def probe_points(configs, pixels_at) -> tuple[list[int], list[int]]:
    """The image sizes and face counts to time: the smallest and largest any level reaches
    (face counts as icosphere sizes, 20 x 4^n, nearest in ratio, at most MAX_PROBE_FACES)."""
    sizes, faces = set(), set()
    for config in configs:
        plan, _ = levels(config)
        sizes.update(lv.size for lv in plan)
        faces.update(lv.faces for lv in plan)
    by_pixels = {}
    for s in sorted(sizes):
        by_pixels.setdefault(pixels_at(s), s)  # sizes above the capture's resolution render the same
    sizes = sorted(by_pixels.values())
    spheres = sorted({min(MAX_PROBE_FACES, 20 * 4 ** max(2, round(np.log(f / 20) / np.log(4))))
                      for f in (min(faces), max(faces))})
    return sorted({sizes[0], sizes[-1]}), spheres


@dataclass
class Plan:
    costs: StepCosts
    presets: dict[str, PresetPlan]
    settings: dict
    probe: dict | None = None  # accuracy_forecast.probe's measurement, the predicted PSNRs' start

    def to_json(self) -> dict:
        return {"costs": self.costs.to_json(), "render_settings": self.settings, "probe": self.probe,
                "presets": {n: p.to_json() for n, p in self.presets.items()}}

    def line(self) -> str:
        """'Draft ≈ 3 min (≈ 24 ± 3 dB), Balanced ≈ 14 min (≈ 26 ± 2 dB), Final ≈ 40 min'"""
        return ", ".join(f"{n.capitalize()} \u2248 {minutes_text(p.minutes)}{' (budget)' if p.capped else ''}"
                         + ("" if p.psnr_text() is None else f" ({p.psnr_text()})") for n, p in self.presets.items())

    def table(self) -> str:
        rows = [("preset", "levels", "sizes px", "faces", "steps", "predicted min", "held-out dB", "F1 (calibration)")]
        for name, p in self.presets.items():
            sizes = sorted({lv.size for lv in p.levels})
            rows.append((name, str(len(p.levels)), f"{sizes[0]}-{sizes[-1]}" if sizes else "-",
                         f"{p.levels[0].faces}-{p.levels[-1].faces}" if p.levels else "-",
                         str(sum(lv.steps for lv in p.levels)), f"{p.minutes:.1f}" + (" (budget)" if p.capped else ""),
                         "-" if p.predicted_psnr is None
                         else f"{p.predicted_psnr:.1f}" + ("+" if p.psnr_extrapolated == "finer" else ""),
                         "-" if p.expected_f1 is None else f"{p.expected_f1:.3f}"))
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        return "\n".join("  ".join(x.ljust(w) for x, w in zip(r, widths)).rstrip() for r in rows)


def psnr_text(predicted: float | None, spread: float | None, extrapolated: str | None = None) -> str | None:
    """A predicted held-out PSNR as the plan line and the panel show it."""
    if predicted is None:
        return None
    if extrapolated == "finer":
        return f"{predicted:.0f}+ dB"
    return f"\u2248 {predicted:.0f}" + ("" if spread is None or extrapolated else f" \u00b1 {spread:.0f}") + " dB"


def minutes_text(minutes: float) -> str:
    return f"{minutes:.1f} min" if minutes < 10 else f"{minutes:.0f} min"


def make_plan(capture, configs: dict, settings, staged: bool, calibration: dict | None = None,
              viewset=None, material_settings=None, initial=None, probe: dict | None = None,
              measure: bool = True) -> Plan | None:
    """This capture's step costs (``step_costs.cached``) and every preset of ``configs`` ({name:
    ReconstructConfig}) predicted from them; ``settings``: the geometry steps' RenderSettings;
    ``calibration``: {preset: calibration entry}; ``initial``: the run's mesh (None:
    icospheres); ``probe``: accuracy_forecast.probe's measurement, for each preset's predicted
    held-out PSNR; ``measure``: False takes only cached costs (None without them)."""
    largest = max(c.max_size for c in configs.values())
    viewset = viewset or ViewSet(capture, largest)
    pixels_at = pixels_for(viewset)
    sizes, faces = probe_points(configs.values(), pixels_at)
    first = next(iter(configs.values()))
    costs = cached(capture, viewset, settings, sizes, faces, first.tone, first.validation_spp,
                   material_settings=material_settings if staged else None, initial=initial, measure_now=measure)
    if costs is None:
        return None
    presets = {name: predict(name, c, costs, pixels_at, len(viewset), staged, (calibration or {}).get(name))
               for name, c in configs.items()}
    gains = load_gains()
    for name, p in presets.items():
        p.predicted_psnr = predicted_psnr(probe, name, gains)
        p.psnr_extrapolated = None if p.predicted_psnr is None else extrapolated(probe, gains)
        p.psnr_spread = None if p.predicted_psnr is None or p.psnr_extrapolated else gain(gains, name)[1]
        p.fixed_s += (probe or {}).get("seconds", 0.0)  # a run that predicts its accuracy probes too
    return Plan(costs, presets, dataclasses.asdict(settings), probe)


# -- for the reconstruct command -----------------------------------------------------------------------
def geometry_settings(config, capture=None, geometry: bool = True) -> "RenderSettings":
    """The render settings the run will most likely use before its effects decision: the
    config's base for point-lit captures; under an environment map, shadow gradients and one
    bounce (the decision keeps them for objects that shadow themselves); ``--effects`` wins."""
    c = config
    base = RenderSettings.for_geometry(c)
    try:
        measured, forced = effects.parse_effects(c.effects)
    except ValueError:
        return base
    likely = measured and capture is not None and capture.environment is not None
    if not forced and not likely:
        return base if geometry else effects.EffectsDecision().settings(base, geometry=False)
    indirect = forced.get("indirect", likely)
    decision = effects.EffectsDecision(max_depth=max(c.max_depth, 3) if indirect else 2,
                                       shadows=bool(forced.get("shadows", likely)),
                                       silhouettes=forced.get("silhouettes", True))
    return decision.settings(base, geometry=geometry)


def capture_plan(capture, configs: dict, calibration: dict | None = None, probe: dict | None = None) -> Plan:
    """``make_plan`` for the reconstruct command: ``configs`` {preset: ReconstructConfig}, the
    staged material when the first config asks for it."""
    first = next(iter(configs.values()))
    return make_plan(capture, configs, geometry_settings(first, capture), staged=first.material == "staged",
                     calibration=calibration, material_settings=geometry_settings(first, capture, geometry=False),
                     probe=probe)
