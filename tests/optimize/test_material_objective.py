"""The constant material model, target views and the objective's gradients (real renders)."""

from __future__ import annotations

import numpy as np
import pytest

from backend import variant
from backend.errors import InputError

variant.choose()

from backend.bench._scenes import render_capture  # noqa: E402
from backend.capture.load import load_capture  # noqa: E402
from backend.capture.model import PointLight  # noqa: E402
from backend.material.constant import ConstantMaterial, parse_spec  # noqa: E402
from backend.optimize.objective import Objective  # noqa: E402
from backend.optimize.views import ViewSet, scaled_camera, validation_views  # noqa: E402
from backend.render.scene import RenderSettings  # noqa: E402
from backend.synth.layout import fibonacci_sphere, orbit_cameras  # noqa: E402
from backend.synth.procedural import icosphere  # noqa: E402


@pytest.fixture(scope="module")
def sphere_capture(tmp_path_factory):
    """A sphere of radius 0.5 at the origin: 6 views at 32 px, a light at each camera."""
    mesh = icosphere(3, 0.5)
    cams = orbit_cameras(fibonacci_sphere(6), np.zeros(3), 0.5, 32)
    frames = [(c, [PointLight(c.centre, np.full(3, 2.0))]) for c in cams]
    out = tmp_path_factory.mktemp("sphere")
    render_capture(out, mesh, frames, albedo=0.6, specular=0.2, roughness=0.4, spp=32)
    return load_capture(out)


def test_material_spec_parsing():
    assert parse_spec("auto") is None
    assert parse_spec("known:0.6,0.5,0.4:0.3:0.2") == ([0.6, 0.5, 0.4], 0.3, 0.2)
    assert parse_spec("known:0.5:0.1:0.9") == ([0.5] * 3, 0.1, 0.9)
    for bad in ("known:1.5,0,0:0.1:0.1", "known:0.5,0.5:0.1:0.1", "glossy", "known:a:b:c"):
        with pytest.raises(InputError):
            parse_spec(bad)


def test_constant_material_values_display_and_persistence(tmp_path):
    known = ConstantMaterial.from_spec("known:0.6,0.5,0.4:0.3:0.2")
    assert known.trainable == ()
    assert known.KIND == "constant" and known.values("albedo").shape == (1, 3)
    assert np.allclose(known.values("albedo"), [0.6, 0.5, 0.4], atol=1e-4)
    assert np.isclose(known.values("roughness")[0, 0], 0.2, atol=1e-4)
    shown = known.display(icosphere(1))
    assert shown.vertex_colors.shape == (42, 3) and np.allclose(shown.attributes["specular"], 0.3, atol=1e-4)
    auto = ConstantMaterial.from_spec("auto")
    assert set(auto.trainable) == {"albedo", "specular", "roughness"}
    latents = auto.parameters()
    auto.load_parameters({"specular": np.array([5.0])})  # in place: the same Dr.Jit array
    assert auto.parameters()["specular"] is latents["specular"] and auto.values("specular")[0, 0] > 0.99
    auto.save(tmp_path / "m.npz")
    back = ConstantMaterial.load(tmp_path / "m.npz")
    assert back.trainable == auto.trainable
    assert np.allclose(back.values("specular"), auto.values("specular"), atol=1e-4)


def test_views_are_premultiplied_once_and_cameras_follow_resizing(sphere_capture):
    views = ViewSet(sphere_capture, 32)
    assert views.premultiplied == len(views)  # synthetic renders are black outside their masks
    half = views.at(16)
    assert half[0].target.shape == (16, 16, 3) and half[0].mask.shape == (16, 16)
    p = np.array([[0.3, -0.2, 0.1]])
    uv32, _ = views.views[0].camera.project(p)
    uv16, _ = half[0].camera.project(p)
    assert np.allclose(uv16, uv32 / 2)
    odd = scaled_camera(views.views[0].camera, 15, 15)
    assert odd.fx == odd.fy
    assert validation_views(32, 6) == sorted(set(validation_views(32, 6))) and len(validation_views(32, 6)) == 6


@pytest.mark.parametrize("tone", ["log", "linear"])
def test_gradients_point_back_to_the_truth(sphere_capture, tone):
    """The sphere shifted along +x: moving further along +x must raise the loss, and a small
    step against the gradient must lower it; a too-dark albedo is pushed up."""
    views = ViewSet(sphere_capture, 32).views
    mesh = icosphere(3, 0.5)
    mesh.vertices += [0.06, 0.0, 0.0]
    material = ConstantMaterial(albedo=0.35, specular=0.2, roughness=0.4, estimate=True)
    settings = RenderSettings(spp=32, integrator="direct_projective", sppc=32, sppp=16, sppi=0)
    objective = Objective(mesh, material, views, settings, tone=tone)
    ids = list(range(len(views)))
    loss, grad, mgrads = objective.loss_and_grad(mesh.vertices, ids, step_seed=3)
    assert np.isfinite(loss) and grad.shape == mesh.vertices.shape
    assert grad[:, 0].sum() > 0  # pushing along +x increases the error
    assert mgrads["albedo"].sum() < 0  # a brighter albedo lowers it
    step = -grad / np.abs(grad).max() * 0.01
    before = objective.loss(mesh.vertices, ids, seed=11, spp=64)
    after = objective.loss(mesh.vertices + step, ids, seed=11, spp=64)
    assert after < before


def test_a_step_over_several_views_sums_their_gradients(sphere_capture):
    """Views after the first in a step re-attach the vertex normals to the vertices without
    rebuilding the scene: the step's gradient is the mean of the views' own, to rounding,
    and the scene renders what a fresh one does after the step."""
    views = ViewSet(sphere_capture, 32).views
    mesh = icosphere(3, 0.5)
    mesh.vertices *= 1.05
    settings = RenderSettings(spp=16, integrator="direct_projective", sppc=16, sppp=8, sppi=0)
    objective = Objective(mesh, ConstantMaterial(albedo=0.5, specular=0.2, roughness=0.4, estimate=True),
                          views, settings)
    loss, grad, mgrads = objective.loss_and_grad(mesh.vertices, [0, 1, 2], step_seed=7)
    singles = [objective.loss_and_grad(mesh.vertices, [view], step_seed=7 + view) for view in range(3)]
    assert np.isclose(loss, np.mean([s[0] for s in singles]), rtol=1e-5)
    mean = np.mean([s[1] for s in singles], axis=0)
    assert np.abs(mean).max() > 0 and np.abs(grad - mean).max() < 1e-4 * np.abs(mean).max()
    assert np.allclose(mgrads["albedo"], np.mean([s[2]["albedo"] for s in singles], axis=0), rtol=1e-4)
    fresh = Objective(mesh, ConstantMaterial(albedo=0.5, specular=0.2, roughness=0.4, estimate=True), views, settings)
    assert objective.loss(mesh.vertices, [0, 1], seed=5) == fresh.loss(mesh.vertices, [0, 1], seed=5)


def test_validation_loss_leaves_out_the_renders_own_noise(sphere_capture):
    """At few samples the plain squared error is mostly the render's variance; the validation
    estimate (two half-sample renders, their residuals multiplied) stays near the error of the
    converged render, so relative convergence tests see the surface's own gains."""
    views = ViewSet(sphere_capture, 32).views
    mesh = icosphere(3, 0.5)  # the true surface: what is left is noise
    settings = RenderSettings(spp=4, max_depth=3, integrator="prb_projective", sppc=4, sppp=4, sppi=0)
    objective = Objective(mesh, ConstantMaterial(albedo=0.6, specular=0.2, roughness=0.4), views, settings)
    ids = list(range(len(views)))
    converged = objective.loss(mesh.vertices, ids, seed=3, spp=1024)
    noisy = objective.loss(mesh.vertices, ids, seed=3, spp=4)
    estimate = objective.validation_loss(mesh.vertices, ids, seed=3, spp=4)
    assert noisy > 1.5 * converged
    assert abs(estimate - converged) < 0.25 * (noisy - converged)
    # the estimate tells a better surface from a worse one as the plain error does
    worse = mesh.vertices * 1.01
    assert objective.validation_loss(worse, ids, seed=3, spp=4) > estimate
