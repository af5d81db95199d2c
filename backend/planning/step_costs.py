"""A capture's step costs, measured: seconds per view of a geometry step, a validation render
and a material step at a few image sizes and face counts, fitted as a + b * pixels + c * faces
(``StepCosts``); planning/time_plan.py's ``predict`` multiplies them by a preset's steps.
``cached`` keeps a measurement beside the capture for its later runs."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import platform
import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import fsio
from ..geometry.init.sphere import sphere_mesh
from ..geometry.subdivide import midpoint
from ..material import factory
from ..optimize.appearance import lit_environment
from ..optimize.objective import Objective
from ..optimize.shadow_samples import charged_seconds
from ..optimize.views import frame_size

MAX_PROBE_FACES = 20480  # larger face counts are extrapolated (a probe step there costs seconds)


@dataclass
class Point:
    """One measured point: seconds per view of each kind of step."""

    size: int
    pixels: int
    faces: int
    gradient: float
    forward: float
    material: float

    def to_json(self) -> dict:
        return {k: round(v, 4) if isinstance(v, float) else v for k, v in dataclasses.asdict(self).items()}


@dataclass
class StepCosts:
    """Seconds per view as a + b * pixels + c * faces, for each kind of step."""

    points: list[Point]
    coefficients: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    seconds: float = 0.0  # what measuring took

    def __post_init__(self):
        if not self.coefficients:
            self.coefficients = {k: fit([(p.pixels, p.faces, getattr(p, k)) for p in self.points])
                                 for k in ("gradient", "forward", "material")}

    def __call__(self, kind: str, pixels: float, faces: float) -> float:
        a, b, c = self.coefficients[kind]
        return a + b * pixels + c * faces

    def to_json(self) -> dict:
        return {"points": [p.to_json() for p in self.points], "seconds": round(self.seconds, 2),
                "model": {k: [float(f"{x:.4g}") for x in v] for k, v in self.coefficients.items()}}

    @classmethod
    def from_json(cls, doc: dict, seconds: float = 0.0) -> "StepCosts":
        """The costs ``to_json`` wrote (refitted from its points); ``seconds``: what getting them took."""
        return cls([Point(**p) for p in doc["points"]], seconds=seconds)


def fit(samples: list[tuple[float, float, float]]) -> tuple[float, float, float]:
    """(a, b, c) of t ~ a + b p + c f by least squares, with b, c >= 0 and a >= 0 (a term that
    comes out negative is dropped and the rest refitted). Fewer than three distinct points fit
    fewer terms."""
    p, f, t = (np.array(x, np.float64) for x in zip(*samples))
    terms = [0] + [i for i, x in ((1, p), (2, f)) if len(set(x.tolist())) >= 2]
    columns = np.stack([np.ones_like(p), p, f], 1)
    while True:
        coef = np.zeros(3)
        coef[terms] = np.linalg.lstsq(columns[:, terms], t, rcond=None)[0]
        negative = [i for i in terms if coef[i] < 0]
        if not negative or len(terms) == 1:
            return tuple(float(max(x, 0.0)) for x in coef)
        terms.remove(min(negative, key=lambda i: coef[i]))


def probe_mesh(capture, faces: int, initial=None):
    """About ``faces`` faces of ``initial`` (the run's initial mesh, split 1-to-4 while that comes
    nearer: its concavities cost shadow and indirect rays a sphere has not), else an icosphere."""
    if initial is None:
        return sphere_mesh(capture, faces)
    while initial.n_faces * 2 < faces:
        initial = midpoint(initial)[0]
    return initial


def measure(capture, viewset, settings, sizes: list[int], faces: list[int], tone: str = "log",
            validation_spp: int = 16, repeats: int = 3, material_settings=None, initial=None) -> StepCosts:
    """Time one view's geometry step, validation render and material step at every (size,
    faces) of ``sizes`` x ``faces`` on this capture with ``settings`` (RenderSettings of the
    geometry steps; the material step with ``material_settings``, default the same), with the
    estimated constant material, on ``probe_mesh`` of ``initial``."""
    start = time.perf_counter()
    material = factory.create("auto")  # the estimated constant material: trainable, as the material steps need
    environment = lit_environment(capture, material)
    first = len(viewset) // 2
    pair = [0, 1] if len(viewset) > 1 else [0]  # a step renders views_per_step views: time two, per view
    points = []
    for n_faces in faces:
        mesh = probe_mesh(capture, n_faces, initial)
        for size in sizes:
            views = (viewset.at(size)[first:] + viewset.at(size))[:len(pair)]
            objective = Objective(mesh, material, views, settings, environment, tone=tone)

            def timed(call) -> float:
                # the median of ``repeats`` steps (5 while short): another process's burst slows single steps
                times = []
                while len(times) < repeats or (len(times) < 5 and sum(times) < 1.0):
                    t0 = time.perf_counter()
                    call(len(times))
                    times.append(time.perf_counter() - t0)
                return float(np.median(times))

            def step(seed):
                return objective.loss_and_grad(mesh.vertices, pair, seed, geometry=True, material=True)
            step(7)  # compiles
            gradient = timed(step) / len(pair)
            if settings.sppi > 0:  # charged at the samples a level keeps (optimize.shadow_samples)
                objective.set_shadow_samples(0)
                step(7)
                gradient = charged_seconds(gradient, timed(step) / len(pair), settings.sppi)
            forward = timed(lambda s: objective.loss(mesh.vertices, pair, s, max(1, validation_spp // 2))) / len(pair)
            if material_settings is not None and material_settings != settings:
                del objective
                objective = Objective(mesh, material, views, material_settings, environment, tone=tone)
            objective.loss_and_grad(mesh.vertices, [0], 7, geometry=False, material=True)
            mat = timed(lambda s: objective.loss_and_grad(mesh.vertices, [0], s, geometry=False, material=True))
            w, h = views[0].camera.width, views[0].camera.height
            points.append(Point(size, w * h, mesh.n_faces, gradient, forward, mat))
            del objective
            dr.flush_malloc_cache()
    return StepCosts(points, seconds=time.perf_counter() - start)


CACHE = ".sft-cache/step_costs.json"  # beside the capture: {key: StepCosts.to_json()}
CACHE_VERSION = 1  # bump when what ``measure`` times changes


def _cpu() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            return next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")),
                        platform.processor())
    except OSError:
        return platform.processor() or platform.machine()


def cache_key(capture, settings, sizes, faces, tone, validation_spp, material_settings, initial) -> str:
    """What a measurement depends on: the capture's file, the render settings, the points
    timed, the initial mesh's size, the Mitsuba variant and the machine."""
    doc = capture.root / "capture.json"
    parts = {"capture": hashlib.sha256(doc.read_bytes()).hexdigest() if doc.is_file() else str(capture.root),
             "settings": dataclasses.asdict(settings),
             "material": None if material_settings is None else dataclasses.asdict(material_settings),
             "sizes": list(sizes), "faces": list(faces), "tone": tone, "spp": validation_spp,
             "initial": None if initial is None else int(initial.n_faces), "variant": mi.variant(),
             "cpu": _cpu(), "cores": os.cpu_count(), "version": CACHE_VERSION}
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:20]


def cached(capture, viewset, settings, sizes: list[int], faces: list[int], tone: str = "log",
           validation_spp: int = 16, material_settings=None, initial=None, measure_now: bool = True):
    """``measure``'s StepCosts, taken from ``CAPTURE/.sft-cache/step_costs.json`` when an
    earlier run on this capture measured them with the same inputs (``cache_key``), else
    measured and kept there (a capture folder that cannot be written keeps nothing); None
    when there is no cached measurement and ``measure_now`` is False."""
    start = time.perf_counter()
    path = capture.root / CACHE
    key = cache_key(capture, settings, sizes, faces, tone, validation_spp, material_settings, initial)
    try:
        entries = json.loads(path.read_text()) if path.is_file() else {}
    except (OSError, ValueError):
        entries = {}
    if isinstance(entries.get(key), dict):
        try:
            return StepCosts.from_json(entries[key], seconds=time.perf_counter() - start)
        except (KeyError, TypeError, ValueError):
            pass
    if not measure_now:
        return None
    costs = measure(capture, viewset, settings, sizes, faces, tone, validation_spp,
                    material_settings=material_settings, initial=initial)
    try:
        fsio.write_json(path, {**{k: v for k, v in entries.items() if k != key}, key: costs.to_json()})
    except OSError:
        pass
    return costs


def pixels_for(viewset):
    """One view's pixels at a level size (the middle view, as measured)."""
    camera = viewset.views[len(viewset) // 2].camera
    return lambda size: int(np.prod(frame_size(camera, size)))


