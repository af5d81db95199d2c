"""``--lighting auto``: the lighting model chosen by its held-out loss on a short probe.

Real captures mix light fixed to the room with light that moves with the camera (a flash, a
lamp on the rig, the operator), and neither the capture's kind nor its name says which
dominates. So each model the capture allows (``candidates``) is fitted for a few steps on a
mesh of the run (its first level's: see below), with a constant diffuse material, on every
frame but ``HELD_OUT`` spread ones, and scored on those:

- ``estimate``: an environment map fixed to the world (backend.lighting.estimated_map);
- ``rig``: the same map fixed to each view's camera (lamps on the camera rig);
- ``world+rig``: the two summed, fitted together (backend.lighting.summed_map);
- ``flash``: a point light at every camera centre (backend.lighting.flash);
- ``captured``: the capture's own map or point lights, when it records any.

The winner has the lowest held-out loss: the mean squared error on sRGB within the masks over
the held-out views, the quantity whose -10 log10 is their PSNR, so the margin in dB is
10 log10(runner-up's loss / winner's). The fit and the score use the run's own machinery
(``Appearance``'s constant material stage, ``lighting.fitted`` for the held-out views), at
``SIZE`` px and few samples, so a candidate costs seconds. Its time counts in the run's time
budget (the budget's clock starts with the command); with a budget, the probe takes at most
``BUDGET_SHARE`` of it, split between the candidates, each stopping after the cycle that
reaches its share (at least one cycle each).

The summed maps (``world+rig``) can light a capture as either map alone does and more, so
they are ranked with a handicap (``SUMMED_HANDICAP_DB``): they win where both kinds of light
are there, not by fitting the held-out frames' noise a little closer.

A run-off makes the choice less fickle: three constant cycles leave the candidates short of
where a run takes them, and on a capture that mixes room and rig light the first two came
within a dB or so, in an order that flipped with the initial mesh, while full runs told them
apart. So when the first two are within ``TIE_DB``, both are fitted again from their start for
``RUNOFF_CYCLES`` cycles and the run-off's held-out loss decides; the report keeps both
rounds (``runoff``). With a budget, the run-off takes ``RUNOFF_SHARE`` of the probe's share.

When the choice is made (``Deferred``): a capture that records no light is probed on the mesh
of the run's first level, not on its initial carve. The carve is too poor a surface to rank
lightings on: its shading errors swamp the differences between the models
(docs/notes/2026-12-02-lighting-after-level.md). So the first level runs under the
``PROVISIONAL`` lighting, the summed maps: they can light the frames as either map alone does (and a flash nearly as the rig map does),
so the first level's geometry steps are bent least by a kind of light the model lacks. The
probe then fits every candidate from its start on that level's mesh, the run continues under
the winner, its fitted lighting taken over from the probe, and one material cycle re-fits the
material under it. A winner whose held-out loss is within ``KEEP_DB`` of the provisional's
(without the handicap) does not replace it: the summed maps hold either single map's light,
the run is already under them, and the probe's constant-material fits do not tell models
that close apart (the run keeps the provisional lighting, ``kept``). The mesh was shaped
under the provisional lighting, which may favour it a little. A capture that records its lights
(``captured`` among the candidates) or has too few frames to probe is decided before the run,
on the initial mesh, as before (its own lights are exact: no surface is needed to rank them)."""

from __future__ import annotations

import dataclasses
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from ..capture.model import Capture
from ..geometry.init import initial_mesh
from ..lighting import fitted, flash
from ..capture.images import linear_to_srgb
from ..optimize.appearance import Appearance
from ..optimize.views import ViewSet
from ..render.scene import RenderSettings, SceneRenderer

EVENT = "lighting_choice"
HELD_OUT = 2  # frames held out of the probe's fits
MIN_FRAMES = 6  # fewer frames: no probe (too few left to fit, or to score)
SIZE = 48  # long side of the probe's images, px
FACES = 1500  # faces of the probe's initial mesh (at most the run's)
ITERATIONS = 30  # Adam iterations of one constant-material cycle
CYCLES = 3  # most cycles per candidate (the constant stage may end sooner)
SPP = 8  # samples per pixel of the fits
SCORE_SPP = 64  # of the held-out renders (a map lights from every direction: its noise must not decide)
BUDGET_SHARE = 0.1  # the most of a time budget the probe takes
TIE_DB = 1.5  # the first two this close (dB of held-out loss): a run-off between them
RUNOFF_CYCLES = 6  # most constant cycles of each run-off fit
RUNOFF_SHARE = 0.5  # of the probe's time share, kept for the run-off
# the summed maps hold a single map's light and more: they are ranked as if their loss were
# this many dB higher, so they win only where the second map earns its texels
SUMMED_HANDICAP_DB = 0.5
SEED = 9_000_011
PROVISIONAL = "world+rig"  # the lighting of the first level while the choice waits for its mesh
# a probe winner this close to the provisional lighting (held-out dB, no handicap) does not replace it
KEEP_DB = TIE_DB
NAMES = {"estimate": "world map", "rig": "rig map", "world+rig": "world + rig maps", "flash": "flash at the camera",
         "captured": "captured lights"}


LIVE = "_lighting"  # a result's fitted lighting object (in memory only, dropped from the report)


def candidates(capture: Capture) -> list[str]:
    """The models ``capture`` allows: the captured lighting when it records a map or point
    lights, and the three fitted ones (which need nothing but the frames)."""
    own = capture.environment is not None or capture.has_point_lights
    return (["captured"] if own else []) + ["estimate", "rig", "world+rig", "flash"]


def held_out(n: int, count: int = HELD_OUT) -> list[int]:
    """``count`` frame indices spread over ``range(n)``, away from its ends (an orbit's first
    and last frames see nearly the same side)."""
    return sorted({int(round((k + 0.5) * n / count)) % n for k in range(count)})


def _copy(capture: Capture, frames) -> Capture:
    """A capture of ``frames`` whose light lists are its own (``flash.place`` edits them in place)."""
    return dataclasses.replace(capture, frames=[dataclasses.replace(f, lights=list(f.lights)) for f in frames])


def _probe_config(config):
    """The run's settings as the probe fits with them: staged constant stage, direct light, tiny images."""
    return dataclasses.replace(config, material="staged", n_materials=1, known_albedo=None, map_calibrated=False,
                               exposure="off", spp=SPP, max_depth=2, coarse_size=SIZE, max_size=SIZE,
                               light_first_cycles=RUNOFF_CYCLES, track_accuracy=False)


def _rank(result: dict) -> float:
    """The loss a candidate is ranked by: its held-out loss, the summed maps' raised by
    ``SUMMED_HANDICAP_DB``."""
    return result["loss"] * (10 ** (SUMMED_HANDICAP_DB / 10) if result["model"] == "world+rig" else 1.0)


def _margin(winner: dict, second: dict) -> float:
    """10 log10(runner-up's ranked loss / winner's), dB (``_rank``)."""
    return 10 * math.log10(_rank(second) / _rank(winner)) if winner["loss"] > 0 else math.inf


def held_out_loss(renders: list[np.ndarray], views) -> float:
    """Mean squared error on sRGB (clipped to [0, 1]) within the masks, pooled over ``views``
    (the quantity of backend.metrics.image.psnr)."""
    total, weight = 0.0, 0.0
    for image, view in zip(renders, views):
        pred = linear_to_srgb(np.clip(image[..., :3], 0, 1)).astype(np.float64)
        target = linear_to_srgb(np.clip(view.target, 0, 1)).astype(np.float64)
        w = np.ones(pred.shape[:2]) if view.mask is None else np.clip(view.mask, 0, 1)
        total += float((((pred - target) ** 2).mean(-1) * w).sum())
        weight += float(w.sum())
    return total / max(weight, 1e-12)


def _fit_and_score(mode: str, fit: Capture, held: Capture, mesh, config, seconds: float, folder: Path,
                   views, held_views, most_cycles: int = CYCLES) -> dict:
    """One candidate: fitted on ``fit``'s views for up to ``most_cycles`` constant cycles
    (stopping once ``seconds`` are spent), scored on ``held``'s."""
    start = time.perf_counter()
    fit = _copy(fit, fit.frames)
    held = _copy(held, held.frames)
    cfg = dataclasses.replace(config, lighting=mode)
    if mode != "captured":
        fit.environment = None  # withheld: the model fits the light
    if mode == "flash":
        flash.place(fit, 1.0)
    lights = {f.name: f.lights for f in fit.frames}
    views = [dataclasses.replace(v, lights=lights[v.name]) for v in views]
    appearance = Appearance(fit, cfg, emit=lambda *a, **k: {})
    appearance.driver.settings = dataclasses.replace(appearance.driver.settings, iterations=ITERATIONS,
                                                     check_every=0, seed=config.seed)
    appearance.start_lighting(folder)
    material = appearance.initial_material(mesh, views)
    material.disable("specular")
    cycles = 0
    while cycles < most_cycles and appearance.driver.stage == "constant":
        if appearance.material_cycle(mesh, material, views, level=0) is None:
            break
        cycles += 1
        if time.perf_counter() - start >= seconds:
            break
    lit = fitted.light_views(held, fitted.from_live(appearance.lighting, material))
    by_name = {f.name: f.lights for f in lit.frames}
    renderer = SceneRenderer(mesh, material.field, [v.camera for v in held_views],
                             [by_name[v.name] for v in held_views], lit.environment,
                             RenderSettings(spp=SCORE_SPP, max_depth=2, integrator="path"))
    renders = [renderer.render_numpy(i, seed=SEED + i) for i in range(len(held_views))]
    loss = held_out_loss(renders, held_views)
    return {"model": mode, "name": NAMES[mode], "loss": loss,
            "psnr": round(-10 * math.log10(loss), 3) if loss > 0 else math.inf,
            "cycles": cycles, "seconds": round(time.perf_counter() - start, 3), LIVE: appearance.lighting}


def choose(capture: Capture, config, emit, budget_s: float | None = None, modes: list[str] | None = None,
           mesh=None, probed_on: str = "initial mesh", fitted: dict | None = None, announce: bool = True) -> dict:
    """The probe on ``capture`` (not changed): report.json ``lighting_choice``.

    ``config``: the run's settings; ``emit``: the run's emitter (a ``stage`` event
    ``lighting:probe``, a ``progress`` event per candidate, then the ``lighting_choice`` event);
    ``budget_s``: the run's time budget (None: none); ``mesh``: the initial mesh to probe on
    (the run's own, carved from every frame it fits, the held-out two included: all candidates
    share it, so it favours none, and the run need not carve twice), else one carved from the
    probe's fitted frames at ``FACES``; ``probed_on``: what that mesh is, in words (the report's
    ``probed_on``); ``fitted``: a dict that receives the winner's fitted lighting object under
    its model's name (None for ``captured``), for the run to continue from; ``announce``: emit
    the ``lighting_choice`` event here (else the caller does). Returns {"winner", "runner_up",
    "margin_db", "candidates": [{"model", "name", "loss", "psnr", "cycles", "seconds"}],
    "held_out": [frame names], "size", "faces", "probed_on", "seconds", "line"}; with too few
    frames to hold any out, the world map (the default before the probe existed), with
    ``candidates`` empty and a ``note``."""
    start = time.perf_counter()
    modes = modes or candidates(capture)
    n = len(capture.frames)
    if n < MIN_FRAMES or len(modes) == 1:
        winner = modes[0] if len(modes) == 1 else ("captured" if "captured" in modes else "estimate")
        out = {"winner": winner, "runner_up": None, "margin_db": None, "candidates": [], "held_out": [],
               "size": SIZE, "seconds": 0.0,
               "note": f"not probed: {n} frames ({MIN_FRAMES} needed)" if n < MIN_FRAMES else "one candidate",
               "probed_on": None, "line": f"lighting: {NAMES[winner]} (not probed)"}
        if announce:
            emit(EVENT, **out)
        return out
    emit("stage", stage="lighting:probe", level=0, faces=0)
    ids = set(held_out(n))
    cfg = _probe_config(config)
    fit = _copy(capture, [f for i, f in enumerate(capture.frames) if i not in ids])
    held = _copy(capture, [f for i, f in enumerate(capture.frames) if i in ids])
    if mesh is None:
        mesh, _ = initial_mesh(fit, config.init, min(FACES, config.initial_faces))
    views = ViewSet(fit, SIZE).at(SIZE)
    held_views = ViewSet(held, SIZE).at(SIZE)
    share = math.inf if budget_s is None else BUDGET_SHARE * budget_s - (time.perf_counter() - start)
    results = []
    runoff = None
    with tempfile.TemporaryDirectory(prefix="sft-lighting-") as folder:
        first_share = share * (1 - RUNOFF_SHARE)
        for k, mode in enumerate(modes):
            results.append(_fit_and_score(mode, fit, held, mesh, cfg, first_share / len(modes), Path(folder),
                                          views, held_views))
            emit("progress", stage="lighting:probe", level=0, iteration=k + 1, iterations=len(modes),
                 loss=results[-1]["loss"], faces=mesh.n_faces)
        ranked = sorted(results, key=_rank)
        if _margin(ranked[0], ranked[1]) < TIE_DB:
            left = share - (time.perf_counter() - start) if budget_s is not None else math.inf
            runoff = [_fit_and_score(r["model"], fit, held, mesh, cfg, left / 2, Path(folder), views, held_views,
                                     RUNOFF_CYCLES) for r in ranked[:2]]
            ranked = sorted(runoff, key=_rank) + ranked[2:]
    winner, second = ranked[0], ranked[1]
    margin = _margin(winner, second)
    if fitted is not None:
        fitted[winner["model"]] = winner[LIVE]
    for r in results + (runoff or []):
        r["loss"] = round(r["loss"], 8)
        r.pop(LIVE, None)
    out = {"winner": winner["model"], "runner_up": second["model"], "margin_db": round(margin, 3),
           "candidates": results, "runoff": runoff, "held_out": [capture.frames[i].name for i in sorted(ids)],
           "size": SIZE, "faces": mesh.n_faces, "probed_on": probed_on, "seconds": round(time.perf_counter() - start, 3),
           "line": f"lighting: {winner['name']}, by {margin:.1f} dB over the {second['name']}"
                   + (" (run-off)" if runoff else "") + ("" if probed_on == "initial mesh" else f", on the {probed_on}")}
    if announce:
        emit(EVENT, **out)
    return out


def deferred(capture: Capture, modes: list[str] | None = None) -> bool:
    """Whether the choice waits for the first level's mesh (``Deferred``): the capture records
    no light of its own and has the frames to probe."""
    modes = modes or candidates(capture)
    return "captured" not in modes and len(modes) > 1 and len(capture.frames) >= MIN_FRAMES


class Deferred:
    """The choice made after the run's first level (``reconstruct``'s ``lighting_probe``): the
    run starts under ``PROVISIONAL``, calls ``choose`` with the fitted capture and the level's
    mesh, takes over the winner's lighting, and emits the event with ``announce`` once its
    snapshot holds the winner (so a resumed run finds the event only with the winner's files)."""

    provisional = PROVISIONAL

    def __init__(self, config, modes: list[str], budget_s: float | None):
        self.config, self.modes, self.budget_s = config, modes, budget_s

    def choose(self, capture: Capture, mesh, level: int, emit) -> tuple[dict, object]:
        """(report.json ``lighting_choice``, the winner's fitted lighting object or None) on
        ``mesh``, the mesh that level ``level`` ended with under the provisional lighting."""
        fitted: dict = {}
        where = f"level {level} mesh ({self.provisional} provisional)"
        choice = choose(capture, self.config, emit, self.budget_s, modes=self.modes, mesh=mesh, probed_on=where,
                        fitted=fitted, announce=False)
        choice.update(provisional=self.provisional, level=level)
        self.settle(choice)
        return choice, None if choice["kept"] else fitted.get(choice["winner"])

    def settle(self, choice: dict) -> dict:
        """``choice`` with the provisional lighting as its winner when the probe's winner is
        within ``KEEP_DB`` of it (``kept`` true; ``runner_up`` the probe's winner, ``margin_db``
        minus the gap), else as the probe left it (``kept`` false)."""
        gap = self.gap(choice)
        choice["kept"] = gap is not None and gap < KEEP_DB
        if choice["kept"]:
            best = choice["winner"]
            choice.update(winner=self.provisional, runner_up=best, margin_db=round(-gap, 3),
                          line=f"lighting: {NAMES[self.provisional]} kept, {gap:.1f} dB behind the {NAMES[best]} "
                               f"(under {KEEP_DB:g} dB), on the {choice['probed_on']}")
        return choice

    def gap(self, choice: dict) -> float | None:
        """10 log10(provisional's held-out loss / the winner's), dB, without the handicap, from the
        run-off when both were in it, else from the first round; None when the provisional won."""
        if choice["winner"] == self.provisional:
            return None
        for round_ in (choice.get("runoff") or [], choice["candidates"]):
            losses = {r["model"]: r["loss"] for r in round_}
            if self.provisional in losses and choice["winner"] in losses and losses[choice["winner"]] > 0:
                return 10 * math.log10(losses[self.provisional] / losses[choice["winner"]])
        return None

    @staticmethod
    def announce(emit, choice: dict) -> None:
        emit(EVENT, **choice)


def resumed(events: list[dict]) -> dict | None:
    """The choice an earlier run in the folder made (its last ``lighting_choice`` event), or None."""
    for event in reversed(events):
        if event.get("event") == EVENT and event.get("winner"):
            return {k: v for k, v in event.items() if k not in ("event", "time")}
    return None
