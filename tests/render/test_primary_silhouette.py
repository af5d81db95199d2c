"""The primarily visible silhouette term of ``render.projective`` against Mitsuba's plugin:
the plugin's term when switched off, the same estimate in expectation when on, and no work
when no vertex is differentiated (real renders, tiny sizes)."""

import numpy as np
import pytest

from backend import variant

variant.choose()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from backend.capture.model import Camera, Environment  # noqa: E402
from backend.render.fields import ConstantField  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

RES = 24


@pytest.fixture(scope="module")
def renderer():
    ball = procedural.icosphere(2, 0.5)
    ball.vertices *= np.array([1.0, 0.8, 1.1])  # not a sphere: silhouettes differ between views
    cams = [Camera(RES, RES, 30.0, 30.0, RES / 2, RES / 2, layout.look_at(e, [0, 0, 0])) for e in ([0, -3, 1], [2, -2, -1])]
    settings = RenderSettings(spp=4, max_depth=3, integrator="prb_projective", sppc=0, sppp=64, sppi=0)
    return SceneRenderer(ball, ConstantField([0.7, 0.6, 0.5], 0.0, 0.5), cams, [[]] * 2,
                         Environment("procedural", 1.0, 0.0), settings, env_pixels=procedural.sky(32, 30.0))


def _integrator(renderer, **props):
    d = renderer.settings.integrator_dict()
    d.update(props)
    return mi.load_dict(d)


def _vertex_gradient(renderer, integrator, seeds, views=(0, 1)) -> np.ndarray:
    """d sum(image) / d vertices of the silhouette term alone (sppc = 0), summed over views and
    averaged over seeds."""
    total = 0.0
    for seed in seeds:
        v = mi.Float(renderer.object.vertex_positions_buffer().numpy())
        dr.enable_grad(v)
        renderer.params[renderer.vertex_key] = v
        renderer.params.update()
        for k, view in enumerate(views):
            if k:
                renderer.object.recompute_vertex_normals()
            img = mi.render(renderer.scene, renderer.params, sensor=renderer.sensors[view], seed=seed, spp=0,
                            integrator=integrator)
            dr.backward(dr.sum(img, axis=None))
        total = total + np.array(dr.grad(v), np.float64)
    return total / len(seeds)


def test_the_run_uses_the_projects_term(renderer):
    assert renderer.settings.integrator_dict()["type"] == "sft_prb_projective"
    assert renderer.scene.integrator().silhouette_once


def test_switched_off_it_is_mitsubas_term_sample_for_sample(renderer):
    plugin = _vertex_gradient(renderer, _integrator(renderer, type="prb_projective"), [3])
    off = _vertex_gradient(renderer, _integrator(renderer, silhouette_once=False), [3])
    assert np.abs(plugin).max() > 0
    np.testing.assert_allclose(off, plugin, rtol=1e-4, atol=1e-6 * np.abs(plugin).max())


def test_it_estimates_mitsubas_term(renderer):
    """Two unbiased estimates of one term: their difference is within the noise of one of them,
    judged by the spread between its own halves."""
    seeds = list(range(10, 18))
    plugin = [_vertex_gradient(renderer, _integrator(renderer, type="prb_projective"), [s]) for s in seeds]
    ours = [_vertex_gradient(renderer, _integrator(renderer), [s]) for s in seeds]
    a, b = np.mean(plugin, 0).ravel(), np.mean(ours, 0).ravel()
    cos = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    noise = np.linalg.norm(np.mean(plugin[::2], 0) - np.mean(plugin[1::2], 0)) / 2  # one mean's error, about
    assert cos > 0.9, cos
    assert np.linalg.norm(a - b) < 3 * np.sqrt(2) * noise, (np.linalg.norm(a - b), noise)


def test_without_differentiated_vertices_the_term_is_not_traced(renderer):
    """A material-only pass: the material's gradient is the plugin's (its silhouette term gives
    the material nothing), and no kernel of the silhouette samples' width is launched (as the
    plugin's lazy term is never evaluated when nothing needs it)."""
    sppc, sppp = 4, 16
    width = RES * RES * sppp
    grads, widths = [], []
    for integrator in (_integrator(renderer, type="prb_projective", sppc=sppc, sppp=sppp),
                       _integrator(renderer, sppc=sppc, sppp=sppp)):
        renderer.params[renderer.vertex_key] = mi.Float(renderer.object.vertex_positions_buffer().numpy())
        renderer.params.update()
        albedo = renderer.field.albedo
        dr.enable_grad(albedo)
        img = mi.render(renderer.scene, renderer.params, sensor=renderer.sensors[0], seed=5, spp=0,
                        integrator=integrator)
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # clears it
        dr.backward(dr.sum(img, axis=None))
        grads.append(np.array(dr.grad(albedo)))
        widths.append({k["size"] for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT})
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        dr.disable_grad(albedo)
    assert np.abs(grads[0]).max() > 0
    np.testing.assert_allclose(grads[1], grads[0], rtol=1e-4, atol=1e-6 * np.abs(grads[0]).max())
    assert width not in widths[0] | widths[1], widths
