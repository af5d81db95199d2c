"""The material schedule: which stage (constants, textured diffuse, textured specular) the
next cycle runs, and ``run_cycle``, which runs it and undoes a cycle that made the full-view
loss worse."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import mitsuba as mi

from .model import MeshColorMaterial
from .stages import (ENV_SCALE, FitResult, FitSettings, check_views, evaluate_loss, fit_constants, fit_diffuse,
                     fit_specular)


@dataclass
class MaterialSchedule:
    """Which material stage the next cycle runs; advances when the loss stops improving or a
    cycle is undone (the constant stage also after ``constant_cycles``)."""

    constant_cycles: int = 5
    restart_cycles: int = 1  # constant cycles after a re-mesh reset
    patience: int = 1  # cycles without improvement that end a spatially varying stage
    min_improvement: float = 0.01  # relative loss decrease that counts as improving
    stage: str = "constant"
    cycle: int = 0  # cycles run in the current stage
    light_fitted: bool = False
    best: float = math.inf
    stale: int = 0
    final: bool = False  # the textures' last round on the converged geometry has begun
    cycle_limit: int | None = None  # cycles after which the current stage ends anyway (a refinement: 1)
    history: list = field(default_factory=list)

    STAGES = ("constant", "diffuse", "specular", "done")

    def report(self, loss: float, reverted: bool = False) -> str:
        """Record the loss of the cycle just run; returns the stage of the next cycle. A cycle
        that had to be undone ends its stage: the next one would start from the same material
        and mesh."""
        self.history.append((self.stage, float(loss)))
        self.cycle += 1
        if reverted:
            self.stale = self.patience
        elif loss < self.best * (1 - self.min_improvement):
            self.best, self.stale = loss, 0
        else:
            self.stale += 1
        # constants end after constant_cycles, or earlier once they stop improving (a short
        # run without re-meshing must still reach the textured stages); the others on patience
        limit = self.constant_cycles if self.stage == "constant" else self.cycle_limit
        if (limit is not None and self.cycle >= limit) or self.stale >= self.patience:
            self.stage = self.STAGES[self.STAGES.index(self.stage) + 1]
            self.cycle, self.stale, self.cycle_limit = 0, 0, None
            self.best = loss
        return self.stage

    def finalise(self, patience: int = 2, last: str = "specular") -> None:
        """Geometry has converged: the textured stages run once more on the final surface, each
        until ``patience`` cycles stop improving. Textures that reached their ``last`` stage
        ("diffuse" without a specular lobe) run it again; the specular stage fits every channel,
        highlights included, so no final diffuse cycle (highlights masked) precedes it: the
        specular stage would undo it."""
        if self.final:
            return
        self.final = True
        if self.stage in ("specular", "done"):
            self.stage = last
        self.cycle, self.stale, self.best, self.patience = 0, 0, math.inf, patience

    def refine(self, stage: str = "specular", cycles: int = 1) -> None:
        """The geometry moved under the finished material: its last stage (the specular stage
        fits every channel, highlights included) runs again for ``cycles`` (one by default: a
        second undoes the first)."""
        self.stage, self.cycle, self.stale, self.best, self.patience = stage, 0, 0, math.inf, 1
        self.cycle_limit = cycles

    def restart(self, constant_cycles: int) -> None:
        """The material restarted from grey on the final surface (the relight under a fitted
        lighting): the constant stage again, at most ``constant_cycles``, then the textures."""
        self.stage, self.cycle, self.stale, self.best, self.cycle_limit = "constant", 0, 0, math.inf, None
        self.constant_cycles = constant_cycles

    def skip_to(self, stage: str) -> None:
        """Start ``stage`` now (a later one than the current), e.g. when the time left holds
        only one more cycle and the last stage has not had its turn."""
        if self.STAGES.index(stage) > self.STAGES.index(self.stage):
            self.stage, self.cycle, self.stale, self.best, self.cycle_limit = stage, 0, 0, math.inf, None

    def on_remesh(self) -> None:
        """The material restarted from grey: a short constant stage, then textures again."""
        self.stage, self.cycle, self.stale, self.best = "constant", 0, 0, math.inf
        self.constant_cycles = self.restart_cycles


def saved_values(material: MeshColorMaterial) -> tuple[dict, float]:
    """Every channel's values and kind, and the light factor: what ``restore_values`` puts back."""
    return {n: (material.values(n).copy(), material.channels[n].kind) for n in material.CHANNELS}, material.light_factor


def restore_values(material: MeshColorMaterial, saved: tuple[dict, float], renderer=None) -> None:
    """Put back what ``saved_values`` saved (``renderer``: its lighting scale follows the factor)."""
    channels, k = saved
    for name, (values, kind) in channels.items():
        material.set_values(name, values, kind)
    if renderer is not None and ENV_SCALE in renderer.params and k != material.light_factor:
        renderer.params[ENV_SCALE] = mi.Float(float(renderer.params[ENV_SCALE][0]) * k / material.light_factor)
        renderer.params.update()
    material.light_factor = k


def run_cycle(schedule: MaterialSchedule, renderer, images, weights, material: MeshColorMaterial,
              settings: FitSettings | None = None, emit=None, loss_spp: int = 0, lighting=None) -> FitResult:
    """Run the schedule's current stage once, then report the full-view loss to the schedule.
    A stage that raises that loss (a diverging fit) is undone: the material never gets worse.
    ``lighting`` (an estimated environment) is fitted with the material and undone with it."""
    settings = settings or FitSettings()
    stage = schedule.stage
    if stage == "done":
        return FitResult("done")
    before = evaluate_loss(renderer, images, weights, material, loss_spp)
    saved = saved_values(material)
    saved_light = None if lighting is None else lighting.latent.copy()
    if stage == "constant":
        result = fit_constants(renderer, images, weights, material, settings, emit, lighting=lighting)
    elif stage == "diffuse":
        result = fit_diffuse(renderer, images, weights, material, settings,
                             light=not schedule.light_fitted and lighting is None, emit=emit, lighting=lighting)
        schedule.light_fitted = True
    elif stage == "specular":
        spec = settings if settings.variance_weight else dataclasses.replace(settings, variance_weight=0.1)
        check = set(check_views(len(images), settings.check_every))
        fitted = [v for v in range(len(images)) if v not in check] if check else None
        result = fit_specular(renderer, images, weights, material, spec, emit=emit, views=fitted, lighting=lighting)
    after = evaluate_loss(renderer, images, weights, material, loss_spp)
    if not after <= before:
        restore_values(material, saved, renderer)
        if lighting is not None:
            lighting.latent = saved_light
            lighting.fit().reset(renderer)
        result.reverted, after = True, before
    schedule.report(after, result.reverted)
    return result
