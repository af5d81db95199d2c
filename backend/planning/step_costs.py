"""A capture's step costs, measured: seconds per view of a geometry step, a validation render
and a material step at a few image sizes and face counts, fitted as a + b * pixels + c * faces
(``StepCosts``); planning/time_plan.py's ``predict`` multiplies them by a preset's steps."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np

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


def pixels_for(viewset):
    """One view's pixels at a level size (the middle view, as measured)."""
    camera = viewset.views[len(viewset) // 2].camera
    return lambda size: int(np.prod(frame_size(camera, size)))


