"""The loop's gradients (projective vertex gradient, mesh-color latents) against central
finite differences."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ... import variant
from ...material.constant import ConstantMaterial
from ...material.model import MeshColorMaterial
from ...optimize.objective import Objective
from ...optimize.views import View
from ...render.fields import ConstantField
from ...render.scene import RenderSettings, SceneRenderer
from ...synth.procedural import blob, icosphere
from .results import GRADIENT_TOLERANCE, KNOWN, Result
from .scenes import lamp_lights, orbit


# -- gradients against finite differences ------------------------------------------------------------------
def _target_views(count: int = 2):
    """The blob at 32 px from ``count`` cameras, each under its own lamp: the loss's targets."""
    cams = orbit(count, 32)
    lights = lamp_lights(cams)
    truth = SceneRenderer(blob(3), ConstantField(0.6, 0.2, 0.4), cams, lights, settings=RenderSettings(spp=64),
                          rgba=True)
    views = []
    for i, cam in enumerate(cams):
        rgba = truth.render_numpy(i, seed=i)
        views.append(View(f"{i}", cam, rgba[..., :3], rgba[..., 3], lights[i]))
    return views


def _compare(result: Result, ad: dict[str, float], fd: dict[str, float]) -> None:
    errors = {name: abs(ad[name] - fd[name]) / max(abs(fd[name]), 1e-30) for name in fd}
    result.notes["relative_errors"] = {k: round(v, 4) for k, v in errors.items()}
    result.notes["ad"] = {k: float(f"{v:.6g}") for k, v in ad.items()}
    result.notes["fd"] = {k: float(f"{v:.6g}") for k, v in fd.items()}
    for name, err in errors.items():
        result.check(err <= GRADIENT_TOLERANCE, f"{name}: AD {ad[name]:.5g} vs FD {fd[name]:.5g} ({100 * err:.1f}%)")
    result.steps = len(errors)
    result.final_loss = max(errors.values())


def gradient_geometry(work: Path, quick: bool) -> Result:
    """The loop's projective vertex gradient (two views, each under its own lamp, log-tone
    masked loss) against central finite differences of the same loss along smooth
    displacement fields: translations along x, y, z and a bump along the normals."""
    variant.choose()
    start = time.perf_counter()
    result = Result("gradient_geometry")
    mesh = icosphere(3, 0.5)
    spp = 64 if quick else 256
    settings = RenderSettings(spp=spp, integrator="direct_projective", sppc=spp, sppp=spp, sppi=0)
    objective = Objective(mesh, ConstantMaterial.from_spec(KNOWN), _target_views(), settings)
    v0, ids = mesh.vertices, [0, 1]
    normals = v0 / np.linalg.norm(v0, axis=1, keepdims=True)
    fields = {"translate_x": np.tile([1.0, 0, 0], (len(v0), 1)), "translate_y": np.tile([0, 1.0, 0], (len(v0), 1)),
              "translate_z": np.tile([0, 0, 1.0], (len(v0), 1)),
              "bump": normals * (np.sin(6 * v0[:, :1]) * np.cos(4 * v0[:, 1:2]))}
    grad = np.mean([objective.loss_and_grad(v0, ids, 1000 + s)[1] for s in range(8)], axis=0)
    ad = {name: float(np.sum(grad * d)) for name, d in fields.items()}
    h, fd_spp = 0.01, 1024
    fd = {name: float(np.mean([(objective.loss(v0 + h * d, ids, s, fd_spp) - objective.loss(v0 - h * d, ids, s, fd_spp))
                               / (2 * h) for s in range(2)])) for name, d in fields.items()}
    _compare(result, ad, fd)
    result.seconds = round(time.perf_counter() - start, 1)
    return result


def gradient_meshcolors(work: Path, quick: bool) -> Result:
    """The loop's gradient with respect to mesh-color latents (r = 2, every channel spatial,
    random values with a visible highlight; two views, each under its own lamp) against
    central finite differences at 1024 spp along random latent directions, per channel and
    all together."""
    variant.choose()
    start = time.perf_counter()
    result = Result("gradient_meshcolors")
    mesh = icosphere(2, 0.5)
    material = MeshColorMaterial(mesh, 2)
    rng = np.random.default_rng(1)
    ranges = {"albedo": (0.2, 0.8), "specular": (0.5, 0.9), "roughness": (0.1, 0.4)}  # a visible highlight
    for name, (width, _, _) in material.CHANNELS.items():
        material.make_spatial(name)
        material.set_values(name, rng.uniform(*ranges[name], (material.layout.n_samples, width)), "colors")
    spp = 256
    objective = Objective(mesh, material, _target_views(),
                          RenderSettings(spp=spp, integrator="direct_projective", sppc=spp, sppp=4, sppi=0))
    ids = [0, 1]
    z0 = {name: np.array(z, np.float64) for name, z in material.parameters().items()}
    directions = {name: {name: rng.normal(size=z.shape)} for name, z in z0.items()}
    directions["all"] = {name: rng.normal(size=z.shape) for name, z in z0.items()}
    grads = [objective.loss_and_grad(mesh.vertices, ids, 500 + s, geometry=False)[2] for s in range(4)]
    ad = {key: float(np.mean([sum(np.sum(g[n] * d[n]) for n in d) for g in grads])) for key, d in directions.items()}

    def loss_at(step: dict, seed: int) -> float:
        material.load_parameters({n: z0[n] + step.get(n, 0.0) for n in z0})
        return objective.loss(mesh.vertices, ids, 500 + seed, 1024)

    h = 0.01
    fd = {}
    for key, d in directions.items():
        fd[key] = float(np.mean([(loss_at({n: h * x for n, x in d.items()}, s)
                                  - loss_at({n: -h * x for n, x in d.items()}, s)) / (2 * h) for s in range(2)]))
    material.load_parameters(z0)
    _compare(result, ad, fd)
    result.seconds = round(time.perf_counter() - start, 1)
    return result
