"""Held-out accuracy against run time (``--track-accuracy``): which views are held out of
the fit (``split``) and their PSNR scored while the run goes (``AccuracyTracker``)."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..capture.images import read_rgba
from ..capture.load import load_capture
from ..capture.model import Capture
from ..lighting import fitted
from ..material.stages import check_views
from ..metrics.image import psnr
from ..render.scene import RenderSettings, SceneRenderer
from ..optimize.views import ViewSet
from . import tracking_figure

FIGURE = "accuracy_time.png"
# samples per pixel x this when an environment map lights the views: a map lights each point
# from every direction, and at the point-lit count the renders' own noise caps the score
ENV_SPP_FACTOR = 8
SEED = 7_000_003  # fixed render seeds: two scores differ only through mesh and material


@dataclass
class HeldOut:
    """The views a run scores but does not fit, or none (``capture`` None, ``note`` why)."""

    capture: Capture | None = None
    source: str = "off"  # "ground truth" or "every Kth view"
    note: str | None = None  # why nothing is tracked although it was asked for
    fitted: int = 0  # views the run fits


def split(capture: Capture, config) -> tuple[Capture, HeldOut]:
    """(the capture the run fits, its held-out views): a synthetic capture's own ground-truth
    held-out views (``ground_truth.held_out``, a separate capture folder) when it has them, and
    then every view of the capture is fitted as without tracking; otherwise every
    ``held_out_every``-th view (``check_views``: the same choice as the specular check's), left
    out of everything the run fits (initialisation, geometry, material, validation). Too few
    views to hold any out: none, with a ``note``."""
    n = len(capture.frames)
    if not config.track_accuracy:
        return capture, HeldOut(fitted=n)
    rel = (capture.ground_truth or {}).get("held_out")
    path = capture.path(rel) if rel else None
    if path is not None and Path(path).exists():
        return capture, HeldOut(load_capture(path), "ground truth", fitted=n)
    every = config.held_out_every
    ids = set(check_views(n, every))
    if not ids:
        return capture, HeldOut(note=f"accuracy not tracked: {n} views are too few to hold out every {every}th "
                                     f"({2 * every} needed) and the capture has no ground-truth held-out views",
                                fitted=n)
    fitted = dataclasses.replace(capture, frames=[f for i, f in enumerate(capture.frames) if i not in ids])
    held = dataclasses.replace(capture, frames=[f for i, f in enumerate(capture.frames) if i in ids])
    return fitted, HeldOut(held, f"every {every}th view", fitted=n - len(ids))


def spread(count: int, most: int) -> list[int]:
    """At most ``most`` indices spread evenly over ``range(count)``."""
    if count <= most:
        return list(range(count))
    return sorted({round(i * count / most) for i in range(most)})


class _Marking:
    """An emitter that also hands every ``stage`` event to the tracker (its boundaries)."""

    def __init__(self, inner, tracker: AccuracyTracker):
        self.inner, self.tracker = inner, tracker

    def __call__(self, event: str, **fields) -> dict:
        if event == "stage":
            self.tracker.mark(fields)
        return self.inner(event, **fields)

    @property
    def start(self) -> float:
        return self.inner.start


@dataclass
class AccuracyTracker:
    """The held-out series of one run: it scores up to ``accuracy_views`` of them, at ``accuracy_size`` px and
    ``accuracy_spp`` spp (x ``ENV_SPP_FACTOR`` under an environment map) with the current mesh
    and material under the run's fitted lighting
    (backend.lighting.fitted, as ``evaluate`` renders them: the views' own lights x the light
    factor, the estimated map, or the flash at each view's camera), every ``accuracy_every_s``
    seconds of run time and at every level's and stage's end: the mean PSNR on sRGB within the
    masks (backend.metrics.image). The run does not charge that time to its budget. Each score
    is an ``accuracy`` event and a point of ``report.json`` ``accuracy_time``; ``RUN/accuracy_time.png`` (tracking_figure) is redrawn after each one.
    """

    held: HeldOut
    config: object
    clock: object = None  # run time in seconds (Budget.elapsed), set once the budget exists
    points: list[dict] = field(default_factory=list)
    marks: list[dict] = field(default_factory=list)
    scoring_seconds: float = 0.0
    _views: list | None = None
    _map: tuple = (None, None)  # (path, pixels) of the captured environment map, read once
    spp: int | None = None  # of the last score (spp_for)

    @property
    def enabled(self) -> bool:
        return self.held.capture is not None

    def now(self) -> float:
        return float(self.clock()) if self.clock is not None else 0.0

    def observe(self, emit):
        return _Marking(emit, self)

    def mark(self, fields: dict) -> None:
        self.marks.append({"seconds": round(self.now(), 2), "stage": str(fields.get("stage")),
                           "level": fields.get("level")})

    def due(self) -> bool:
        """Whether ``accuracy_every_s`` has passed since the last score."""
        last = self.points[-1]["seconds"] if self.points else -math.inf
        return self.enabled and self.now() - last >= self.config.accuracy_every_s

    def views(self) -> list:
        """The scored views (loaded once): spread over the held-out ones with a non-empty mask."""
        if self._views is None:
            c = self.config
            views = [v for v in ViewSet(self.held.capture, self.size).views
                     if v.mask is None or float(v.mask.sum()) > 0]
            self._views = [views[i] for i in spread(len(views), c.accuracy_views)]
        return self._views

    @property
    def size(self) -> int:
        """Long side of the scored images: accuracy_size, at most the run's finest size."""
        return min(self.config.accuracy_size, self.config.max_size)

    def spp_for(self, environment) -> int:
        """The scores' samples per pixel: ``accuracy_spp``, x ENV_SPP_FACTOR under an environment map."""
        return self.config.accuracy_spp * (ENV_SPP_FACTOR if environment is not None else 1)

    def _pixels(self, env):
        """The map's pixels when they come from a file (read once), else None."""
        if env is None or env.pixels is not None:
            return None
        if self._map[0] != env.path:
            self._map = (env.path, read_rgba(env.path)[0][..., :3])
        return self._map[1]

    def score(self, mesh, material, lighting=None, *, level: int, phase: str, why: str,
              validation_loss: float | None, folder: Path) -> dict:
        """Render and score the views now; the point (the ``accuracy`` event's fields).
        ``lighting``: the run's fitted lighting (``Appearance.lighting``: an estimated map, a
        flash, or None for the captured lights), which lights the views (backend.lighting.fitted)."""
        start, now = time.perf_counter(), self.now()  # the run time at which the model is scored
        c, views = self.config, self.views()
        lit = fitted.light_views(self.held.capture, fitted.from_live(lighting, material))
        lights = {f.name: f.lights for f in lit.frames}
        self.spp = self.spp_for(lit.environment)
        renderer = SceneRenderer(mesh, material.field, [v.camera for v in views], [lights[v.name] for v in views],
                                 lit.environment,
                                 RenderSettings(spp=self.spp, max_depth=c.max_depth, integrator="path"),
                                 env_pixels=self._pixels(lit.environment))
        scores = [psnr(renderer.render_numpy(i, seed=SEED + i)[..., :3], v.target, v.mask)
                  for i, v in enumerate(views)]
        seconds = time.perf_counter() - start
        self.scoring_seconds += seconds
        point = {"seconds": round(now, 2), "psnr": round(float(np.mean(scores)), 3),
                 "validation_loss": validation_loss, "level": level,
                 "stage": self.marks[-1]["stage"] if self.marks else "init", "phase": phase, "why": why,
                 "views": len(views), "scoring_seconds": round(seconds, 3), "figure": FIGURE}
        self.points.append(point)
        tracking_figure.write(Path(folder) / FIGURE, self.points, self.marks, self.title())
        return point

    def title(self) -> str:
        c = self.config
        return (f"held-out PSNR (dB): {len(self.views())} views ({self.held.source}), {self.size} px, "
                f"{self.spp or c.accuracy_spp} spp")

    # -- resume --------------------------------------------------------------------------------
    def state(self) -> dict | None:
        if not self.enabled:
            return None
        return {"points": self.points, "marks": self.marks, "scoring_seconds": round(self.scoring_seconds, 3)}

    def restore(self, state: dict | None) -> None:
        if state and self.enabled:
            self.points = list(state.get("points", [])) + self.points
            self.marks = list(state.get("marks", [])) + self.marks
            self.scoring_seconds += float(state.get("scoring_seconds", 0.0))

    # -- the report ----------------------------------------------------------------------------
    def level_gains(self) -> list[dict]:
        """Each geometry level's held-out PSNR gain: its last score (its material cycle
        included) less the last one before it (the first score for level 0)."""
        ends: dict[int, dict] = {}
        for p in self.points:
            if p["phase"] in ("level", "transition") and p["why"] != "start":
                ends[p["level"]] = p
        out, before = [], self.points[0] if self.points else None
        for level in sorted(ends):
            end = ends[level]
            out.append({"level": level, "psnr": end["psnr"], "psnr_gain_db": round(end["psnr"] - before["psnr"], 3),
                        "seconds": round(end["seconds"] - before["seconds"], 2)})
            before = end
        return out

    def report(self) -> dict | None:
        """report.json ``accuracy_time`` (None when not tracked)."""
        if not self.enabled:
            return {"tracked": False, "note": self.held.note} if self.held.note else None
        c = self.config
        return {"tracked": True, "source": self.held.source, "fitted_views": self.held.fitted,
                "held_out_views": [f.name for f in self.held.capture.frames],
                "scored_views": [v.name for v in self.views()], "size": self.size, "spp": self.spp or c.accuracy_spp,
                "every_s": c.accuracy_every_s, "scoring_seconds": round(self.scoring_seconds, 3),
                "points": self.points, "marks": self.marks, "level_gains": self.level_gains(),
                "figure": FIGURE, "caption": tracking_figure.CAPTION}


def start(capture: Capture, config) -> tuple[Capture, AccuracyTracker]:
    """(the capture the run fits, the tracker of its held-out views) by ``split``: what
    ``optimize.run.reconstruct`` takes as ``tracking``."""
    fitted, held = split(capture, config)
    return fitted, AccuracyTracker(held, config)
