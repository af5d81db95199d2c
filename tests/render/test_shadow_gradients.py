"""Shadow (indirect-silhouette) gradients run with the guiding RenderSettings chooses, and that
estimate agrees with the one of Mitsuba's default octree guiding (real renders, tiny sizes)."""

import dataclasses

import numpy as np
import pytest

from backend import variant

variant.choose()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from backend.capture.model import Camera, Environment  # noqa: E402
from backend.geometry.mesh import Mesh  # noqa: E402
from backend.render import effects, projective  # noqa: E402
from backend.render.fields import ConstantField  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

RES = 32


def _ball_on_floor():
    """A ball above a floor under a low sun: the ball's shadow moves with its vertices."""
    floor = Mesh(np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    ball = procedural.icosphere(2, 0.5)
    ball.vertices[:, 2] += 0.6
    mesh = Mesh(np.vstack([floor.vertices, ball.vertices]), np.vstack([floor.faces, ball.faces + 4]))
    cams = [Camera(RES, RES, 26.0, 26.0, RES / 2, RES / 2, layout.look_at(e, [0, 0, 0.3]))
            for e in ([0, -4, 3], [3, -3, 3])]
    return mesh, cams


@pytest.fixture(scope="module")
def scene():
    mesh, cams = _ball_on_floor()
    return mesh, cams, Environment("procedural", 1.0, 0.0), procedural.sky(64, sun_elevation_deg=25.0)


def _shadow_gradient(scene, settings: RenderSettings, seeds) -> tuple[np.ndarray, object]:
    """The indirect-silhouette part alone (interior and primary-silhouette samples off) of
    d mean(image) / d vertices over every view, averaged over ``seeds``."""
    mesh, cams, env, sky = scene
    renderer = SceneRenderer(mesh, ConstantField([0.7, 0.7, 0.7], 0.0, 0.5), cams, [[]] * len(cams), env, settings,
                             env_pixels=sky)
    integrator = renderer.scene.integrator()
    integrator.sppc = integrator.sppp = 0
    total = np.zeros((mesh.n_vertices, 3))
    for seed in seeds:
        v = mi.Float(mesh.vertices.astype(np.float32).ravel())
        dr.enable_grad(v)
        renderer.params[renderer.vertex_key] = v
        renderer.params.update()
        for view in range(len(cams)):
            if view:
                renderer.object.recompute_vertex_normals()
            img = mi.render(renderer.scene, renderer.params, sensor=renderer.sensors[view], seed=seed, spp=0)
            dr.backward(dr.mean(img, axis=None))
        total += np.array(dr.grad(v), np.float64).reshape(-1, 3)
    return total / len(seeds), integrator


def test_shadow_gradients_run_with_the_chosen_guiding(scene):
    settings = effects.EffectsDecision(shadows=True).settings(RenderSettings(spp=4), geometry=True)
    assert settings.integrator == "direct_projective"
    assert settings.sppi == effects.SHADOW_SPPI and settings.guiding == RenderSettings.guiding
    assert settings.integrator_dict()["guiding"] == RenderSettings.guiding
    # without shadow gradients nothing about guiding reaches the integrator
    assert "guiding" not in effects.EffectsDecision(shadows=False).settings(RenderSettings(), True).integrator_dict()
    grad, integrator = _shadow_gradient(scene, settings, [1])
    assert integrator.guiding == RenderSettings.guiding and integrator.sppi == effects.SHADOW_SPPI
    # the structure the backward pass sampled from: no octree was built
    assert isinstance(integrator.proj_detail.guiding_distr, mi.ad.UniformDistr)
    assert np.linalg.norm(grad[4:]) > 0  # the ball's vertices get a shadow gradient


def test_shadow_gradient_agrees_with_the_octree(scene):
    chosen = effects.EffectsDecision(shadows=True).settings(RenderSettings(spp=4), geometry=True)
    chosen = dataclasses.replace(chosen, sppi=16 * chosen.sppi)
    octree = dataclasses.replace(chosen, guiding="octree", sppi=64)
    g_chosen, _ = _shadow_gradient(scene, chosen, [11, 12])
    g_octree, integrator = _shadow_gradient(scene, octree, [21, 22])
    assert not isinstance(integrator.proj_detail.guiding_distr, mi.ad.UniformDistr)
    a, b = g_chosen[4:].ravel(), g_octree[4:].ravel()  # the ball's vertices
    cos = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    ratio = float(np.linalg.norm(a) / np.linalg.norm(b))
    assert cos > 0.95 and 0.85 < ratio < 1.15, (cos, ratio)  # two unbiased estimates of one term


def test_reused_guiding_is_built_once_per_sensor_until_its_uses_run_out(scene):
    """The benchmark's reuse option: a per-sensor cache, rebuilt after ``guiding_reuse`` passes
    and whenever the connectivity changes."""
    mesh, cams, env, sky = scene
    settings = RenderSettings(spp=4, max_depth=2, integrator="direct_projective", sppi=4, guiding="octree")
    renderer = SceneRenderer(mesh, ConstantField([0.7, 0.7, 0.7], 0.0, 0.5), cams, [[]] * len(cams), env, settings,
                             env_pixels=sky)
    d = settings.integrator_dict()
    d.update(type="sft_direct_projective", guiding_reuse=2)
    integrator = mi.load_dict(d)
    assert isinstance(integrator.proj_detail, projective.ReusedGuiding)
    for step in range(3):
        v = mi.Float(mesh.vertices.astype(np.float32).ravel())
        dr.enable_grad(v)
        renderer.params[renderer.vertex_key] = v
        renderer.params.update()
        img = mi.render(renderer.scene, renderer.params, sensor=renderer.sensors[0], seed=step, spp=0,
                        integrator=integrator)
        dr.backward(dr.mean(img, axis=None))
    assert integrator.proj_detail.builds == 2  # built, reused, rebuilt
