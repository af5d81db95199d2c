"""Hard cases at the renderer level: every value and gradient stays finite.

Extreme materials, extreme lighting and degenerate triangles, at 1-4 spp and tiny
resolution, with silhouette (projective) gradients."""

import numpy as np
import pytest

from backend import variant

variant.choose()
import drjit as dr  # noqa: E402

from backend.capture.model import Camera, Environment  # noqa: E402
from backend.geometry.mesh import Mesh  # noqa: E402
from backend.render.fields import ConstantField  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

RES = 32


def _cameras(n=2, distance=3.0):
    return [Camera(RES, RES, 40.0, 40.0, RES / 2, RES / 2, layout.look_at(d * distance, [0, 0, 0]))
            for d in layout.fibonacci_sphere(n)]


def _finite_gradients(mesh, field, cameras, lights, env=None, env_pixels=None, spp=2, integrator="prb_projective"):
    renderer = SceneRenderer(mesh, field, cameras, lights, env,
                             RenderSettings(spp=spp, max_depth=3, integrator=integrator), env_pixels=env_pixels)
    params = renderer.params
    keys = [renderer.vertex_key] + [f"object.bsdf.{name}" for name in field.arrays()]
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    img = renderer.render(0, params=params, seed=1)
    loss = dr.mean(dr.square(img - 0.3))
    dr.backward(loss)
    grads = {key: np.array(dr.grad(params[key])) for key in keys}
    values = np.array(img)
    return values, float(np.array(loss).ravel()[0]), grads


def _point_lights(cameras, power=6.0):
    return [layout.paper_lights(c, power) for c in cameras]


@pytest.mark.parametrize("specular, roughness", [(0.0, 0.0), (1.0, 0.0), (1.0, 1e-4), (0.5, 1.0), (1.0, 1.0), (0.0, 1.0)])
def test_extreme_materials_keep_values_and_gradients_finite(specular, roughness):
    sphere = procedural.icosphere(3)
    cams = _cameras()
    values, loss, grads = _finite_gradients(sphere, ConstantField([0.9, 0.5, 0.0], specular, roughness), cams,
                                            _point_lights(cams))
    assert np.isfinite(values).all() and np.isfinite(loss)
    for name, g in grads.items():
        assert np.isfinite(g).all(), name
    assert np.abs(grads["object.vertex_positions"]).max() > 0


def test_sun_of_radiance_1e5_beside_a_dim_sky(tmp_path):
    sky = np.full((64, 128, 3), 0.02, np.float32)
    sky[10:12, 40:42] = 1e5
    cams = _cameras()
    values, loss, grads = _finite_gradients(procedural.blob(3), ConstantField([0.5] * 3, 0.8, 0.05), cams,
                                            [[]] * 2, Environment(tmp_path / "env.exr"), sky, spp=1)
    assert np.isfinite(values).all() and np.isfinite(loss)
    assert all(np.isfinite(g).all() for g in grads.values())


def test_degenerate_triangles_duplicates_and_flipped_faces():
    sphere = procedural.icosphere(2)
    v, f = sphere.vertices, sphere.faces.copy()
    f[::7] = f[::7, ::-1]  # flipped faces
    dup = len(v)
    v = np.vstack([v, v[:3], v[0] + [1e-9, 0, 0]])  # duplicate vertices
    zero_area = [[0, dup, 0], [1, 1, 2], [dup + 1, dup + 2, dup + 3]]  # zero-area and collapsed
    sliver = [[0, 1, dup + 3]]
    mesh = Mesh(v, np.vstack([f, zero_area, sliver]))
    cams = _cameras()
    values, loss, grads = _finite_gradients(mesh, ConstantField([0.5] * 3, 0.3, 0.3), cams, _point_lights(cams))
    assert np.isfinite(values).all() and np.isfinite(loss)
    assert all(np.isfinite(g).all() for g in grads.values())


def test_mesh_far_larger_than_the_frame():
    big = procedural.icosphere(4, radius=50.0)
    cams = _cameras(distance=53.0)  # 3 units from a sphere of radius 50: it overfills every frame
    values, loss, grads = _finite_gradients(big, ConstantField([0.5] * 3, 0.2, 0.5), cams, _point_lights(cams))
    assert np.isfinite(values).all() and all(np.isfinite(g).all() for g in grads.values())


def test_one_sample_per_pixel_and_grazing_views():
    sphere = procedural.icosphere(3)
    grazing = [Camera(RES, RES, 400.0, 400.0, RES / 2, RES / 2, layout.look_at([3.0, 0.0, 1.0], [0, 0, 1.0]))]
    values, loss, grads = _finite_gradients(sphere, ConstantField([0.5] * 3, 0.5, 0.2), grazing,
                                            _point_lights(grazing), spp=1)
    assert np.isfinite(values).all() and all(np.isfinite(g).all() for g in grads.values())
