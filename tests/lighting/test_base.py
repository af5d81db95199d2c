"""The fitted-lighting interface (backend.lighting.base): every lighting class in
backend.lighting that has the interface's methods declares it and implements all of it, and
each fit keeps the contract on a tiny real scene, driven through the base type alone."""

from __future__ import annotations

import importlib
import inspect
import math
import pkgutil
from pathlib import Path

import numpy as np
import pytest

from backend import variant

variant.choose()

import backend.lighting  # noqa: E402
from backend.capture.model import Capture, Environment, Frame  # noqa: E402
from backend.lighting.base import LightingFit, LightingModel  # noqa: E402
from backend.lighting.estimated_map import EstimatedEnvironment  # noqa: E402
from backend.lighting.flash import Flash  # noqa: E402
from backend.lighting.light_factor import LightFactor  # noqa: E402
from backend.material.base import CHANNELS  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

LOG2 = math.log(2.0)
SETTINGS = RenderSettings(spp=4, max_depth=2, integrator="path")  # direct light: renders linear in the light


def lighting_classes() -> list[type]:
    """Every class defined in a backend.lighting module."""
    out = []
    for info in pkgutil.iter_modules(backend.lighting.__path__):
        module = importlib.import_module(f"backend.lighting.{info.name}")
        out += [c for _, c in inspect.getmembers(module, inspect.isclass)
                if c.__module__ == module.__name__ and c not in (LightingFit, LightingModel)]
    return out


def having(interface: type) -> list[type]:
    return [c for c in lighting_classes() if all(hasattr(c, m) for m in interface.__abstractmethods__)]


def test_every_fitted_lighting_class_implements_the_interface():
    fits, models = having(LightingFit), having(LightingModel)
    assert {c.__name__ for c in fits} == {"EnvironmentFit", "FlashFit", "LightFactor", "SummedFit"}
    assert {c.__name__ for c in models} == {"EstimatedEnvironment", "Flash", "SummedEnvironment"}
    for c in fits:
        assert issubclass(c, LightingFit) and not inspect.isabstract(c), c
    for c in models:
        assert issubclass(c, LightingModel) and not inspect.isabstract(c), c
    names = [c.NAME for c in fits]
    assert all(names) and len(set(names)) == len(names) and not set(names) & set(CHANNELS)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    mesh = procedural.blob(2)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(2), np.zeros(3), 0.6, 16)
    return mesh, cams, tmp_path_factory.mktemp("base")


def light_factor(scene):
    mesh, cams, _ = scene
    material = MeshColorMaterial(mesh, 1)
    renderer = SceneRenderer(mesh, material.field, cams, [[] for _ in cams], Environment(Path("sky.exr"), 0.5, 0.0),
                             SETTINGS, env_pixels=procedural.sky(16))
    return LightFactor(material, 0.02), renderer


def environment_fit(scene):
    mesh, cams, folder = scene
    estimate = EstimatedEnvironment(np.log(procedural.sky(16) + 0.05).astype(np.float32), folder / "e.exr")
    renderer = SceneRenderer(mesh, MeshColorMaterial(mesh, 1).field, cams, [[] for _ in cams],
                             estimate.environment(), SETTINGS)
    return estimate.fit(), renderer


def flash_fit(scene):
    mesh, cams, folder = scene
    capture = Capture(folder, [Frame(str(k), folder / f"{k}.exr", c) for k, c in enumerate(cams)])
    flash = Flash(capture, [math.log(1.5)])
    renderer = SceneRenderer(mesh, MeshColorMaterial(mesh, 1).field, cams, [f.lights for f in capture.frames], None,
                             SETTINGS)
    return flash.fit(), renderer


@pytest.mark.parametrize("make", [light_factor, environment_fit, flash_fit], ids=lambda f: f.__name__)
def test_a_fit_keeps_the_contract_through_the_base_type(scene, make):
    """Through LightingFit alone: the latent is a log scale of the light (latent + log 2 renders
    twice as bright), the prior ignores the level, ``finish`` leaves the model and the scene at
    the result and ``reset`` brings the scene back to the model."""
    fit, renderer = make(scene)
    assert isinstance(fit, LightingFit) and fit.present(renderer) and fit.lr > 0

    def render():
        return renderer.render_numpy(0, seed=3)[..., :3].astype(np.float64)

    images = [renderer.render_numpy(v, seed=11 + v)[..., :3] for v in range(len(renderer.cameras))]
    fit.prepare(renderer, images, [np.ones(img.shape[:2], np.float32) for img in images])
    start = fit.initial()
    fit.apply(renderer, start)
    before = render()
    assert before.max() > 0
    fit.apply(renderer, start + LOG2)
    brighter = render()
    assert np.allclose(brighter, 2.0 * before, rtol=1e-3, atol=1e-5 * before.max())
    level = float(fit.penalty(start)[0])
    assert level >= 0 and float(fit.penalty(start + LOG2)[0]) == pytest.approx(level, abs=1e-7)

    fit.finish(renderer, start + LOG2)
    assert np.allclose(np.array(fit.initial()), np.array(start) + LOG2, rtol=1e-5, atol=1e-6)
    assert np.allclose(render(), brighter, rtol=1e-4, atol=1e-6)
    fit.apply(renderer, start)
    fit.reset(renderer)
    assert np.allclose(render(), brighter, rtol=1e-4, atol=1e-6)
