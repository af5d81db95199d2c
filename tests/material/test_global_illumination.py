"""Global illumination matters for albedo: the three-plane corner (red, blue, white).

Ground truth is path traced at high spp with 8 bounces. Fitting per-plane albedo with
multi-bounce path tracing recovers it; with direct light only (max_depth = 2) the white
floor absorbs the red and blue interreflections into its albedo."""

import numpy as np

from backend import variant

variant.choose()

from backend.capture.model import Camera, PointLight  # noqa: E402
from backend.material import stages  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout  # noqa: E402
from tests.material.helpers import three_plane_corner  # noqa: E402

TRUTH = np.array([[0.8, 0.8, 0.8], [0.8, 0.1, 0.1], [0.1, 0.1, 0.8]])  # floor, x wall, y wall
RES = 24


def corner_views():
    f = 0.5 * RES / np.tan(np.radians(25))
    eyes = [[2.2, 1.6, 1.5], [1.6, 2.1, 1.7], [2.7, 1.1, 1.2]]
    return [Camera(RES, RES, f, f, RES / 2, RES / 2, layout.look_at(e, [0.3, 0.3, 0.25])) for e in eyes]


def fit_albedo(mesh, labels, cams, lights, images, weights, max_depth):
    material = MeshColorMaterial(mesh, 1, labels, 3)
    material.set_values("specular", 1e-3)
    renderer = SceneRenderer(mesh, material.field, cams, lights, None,
                             RenderSettings(spp=16, max_depth=max_depth, integrator="prb"))
    stages.fit(renderer, images, weights, material, ["albedo"], stages.FitSettings(iterations=60, lr=0.2))
    return material.values("albedo")


def test_multi_bounce_recovers_albedo_and_one_bounce_bakes_in_the_bleed():
    mesh, labels = three_plane_corner(2)
    cams = corner_views()
    lights = [[PointLight(np.array([0.7, 0.6, 1.3]), np.full(3, 1.5))] for _ in cams]
    truth = MeshColorMaterial(mesh, 1, labels, 3)
    truth.set_values("albedo", TRUTH)
    truth.set_values("specular", 1e-4)
    reference = SceneRenderer(mesh, truth.field, cams, lights, None,
                              RenderSettings(spp=512, max_depth=8, integrator="path"), rgba=True)
    rendered = [reference.render_numpy(v, seed=v) for v in range(len(cams))]
    images, weights = [r[..., :3] for r in rendered], [r[..., 3] for r in rendered]

    multi = fit_albedo(mesh, labels, cams, lights, images, weights, max_depth=5)
    assert np.sqrt(np.mean((multi - TRUTH) ** 2)) < 0.03

    single = fit_albedo(mesh, labels, cams, lights, images, weights, max_depth=2)
    floor = single[0]
    assert floor[0] - floor[1] > 0.03 and floor[2] - floor[1] > 0.03  # purple tint: red, blue > green
    assert np.sqrt(np.mean((single - TRUTH) ** 2)) > 2 * np.sqrt(np.mean((multi - TRUTH) ** 2))
