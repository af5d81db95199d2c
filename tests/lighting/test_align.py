"""Lighting alignment: on a synthetic capture (our synth, 8-bit sRGB frames) the environment's
rotation and strength are recovered; the rotation gradient matches finite differences; the
direct-light operator agrees with the path tracer's placement of the map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture import load_capture  # noqa: E402
from backend.capture.images import read_rgba  # noqa: E402
from backend.capture.model import Environment  # noqa: E402
from backend.geometry.init.carve import carve  # noqa: E402
from backend.geometry.init.hull import HullConfig  # noqa: E402
from backend.lighting.align import (AlignConfig, RotationLoss, align_lighting, reduce_environment,  # noqa: E402
                                    shift_columns)
from backend.geometry.raycast import RayCaster, pixel_rays  # noqa: E402
from backend.lighting.transport import transport_matrix  # noqa: E402
from tests.helpers import run_cli  # noqa: E402

ROTATION, STRENGTH = 70.0, 2.0


def _angle_error(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A diffuse grey blob under the procedural sky, rotated and scaled, 12 views of 64 px as PNG."""
    out = tmp_path_factory.mktemp("lighting") / "capture"
    run_cli("synth", "--out", out, "--lighting", "env", "--env-rotation", ROTATION, "--env-strength", STRENGTH,
            "--albedo", "0.5,0.5,0.5", "--specular", 0, "--format", "png", "--views", 12, "--resolution", 64,
            "--spp", 64, "--held-out", 0, check=True)
    capture = load_capture(out)
    assert capture.frames[0].image.suffix == ".png"
    capture.environment = Environment(capture.environment.path)  # what the alignment starts from: unknown
    hull = carve(capture, 3000, HullConfig(grid=64))
    return capture, hull, read_rgba(capture.environment.path)[0][..., :3]


def test_recovers_rotation_and_strength(scene):
    capture, hull, env = scene
    events = []
    alignment = align_lighting(capture, hull, env, AlignConfig(), emit=lambda kind, **f: events.append((kind, f)))
    error = _angle_error(alignment.rotation_z_deg, ROTATION)
    print(f"rotation {alignment.rotation_z_deg:.2f} deg (error {error:.2f}), strength {alignment.strength:.3f} "
          f"(truth {STRENGTH}), gains {np.round(alignment.gains, 3)}, loss {alignment.loss:.4f}, "
          f"{alignment.pixels} pixels, {alignment.seconds:.1f} s")
    assert error < 5.0
    assert abs(alignment.strength / STRENGTH - 1) < 0.10
    assert max(alignment.gains) / min(alignment.gains) < 1.05  # a grey object stays grey
    coarse = dict(alignment.coarse)
    assert len(coarse) == 180 and alignment.loss <= min(coarse.values())  # refinement never worsens the search
    assert [v for _, v in alignment.refine] == sorted((v for _, v in alignment.refine), reverse=True)
    assert {f["stage"] for k, f in events if k == "progress"} >= {"lighting:search", "lighting:transport"}
    doc = alignment.provenance()
    assert doc["aligned"] and len(doc["coarse_curve"]) == 180 and doc["refine_curve"]
    # the frames' background is black (emitters hidden): nothing to take the scale from
    assert alignment.scale_from == "mean albedo 0.5" and alignment.response.provenance == "normalised"

    known = align_lighting(capture, hull, env, AlignConfig(), rotation_z_deg=ROTATION)
    assert known.rotation_z_deg == ROTATION and not known.coarse
    assert abs(known.strength / STRENGTH - 1) < 0.10


def test_rotation_gradient_matches_finite_differences(scene):
    capture, hull, env = scene
    small = reduce_environment(env, 32)
    caster = RayCaster(hull)
    cam = capture.frames[0].camera.scaled(0.5)
    origins, dirs = pixel_rays(cam)
    hits = caster.intersect(origins, dirs)
    hit, points, normals = hits.hit, hits.points, hits.shading_towards(dirs)
    diffuse, glossy = transport_matrix(caster, points[hit], normals[hit], small.shape[1], small.shape[0],
                                       views=-dirs[hit], alpha=0.15)
    rng = np.random.default_rng(1)
    truth = shift_columns(small, 40.0)[0].reshape(-1, 3)
    targets = (diffuse @ truth * [1.1, 1.0, 0.9] + 0.1 * glossy @ truth) * rng.uniform(0.9, 1.1, (len(diffuse), 3))
    step = 360.0 / small.shape[1]
    for matrices in ([diffuse], [diffuse, glossy]):
        loss = RotationLoss(matrices, small, targets)
        for degrees in (3.3, 31.0, 47.9, 200.2):  # away from the kinks at whole-texel shifts
            value, grad, _ = loss(degrees)
            eps = 1e-3 * step
            numeric = (loss(degrees + eps, False)[0] - loss(degrees - eps, False)[0]) / (2 * eps)
            print(f"{len(matrices)} operators, {degrees} deg: analytic {grad:.6g}, finite differences {numeric:.6g}")
            assert abs(grad - numeric) <= 2e-3 * abs(numeric) + 1e-9


def test_operator_matches_the_path_tracer(scene):
    """The transport matrix with a shifted map renders what Mitsuba renders with the rotated map."""
    from backend.render.fields import ConstantField
    from backend.render.scene import RenderSettings, SceneRenderer

    capture, hull, env = scene
    cams = [capture.frames[i].camera.scaled(0.5) for i in (0, 5)]
    small = reduce_environment(env, 64)
    renderer = SceneRenderer(hull, ConstantField(0.5, 0.0, 0.5), cams, [[], []], Environment(Path("env"), 1.0, ROTATION),
                             RenderSettings(spp=256, max_depth=2), env_pixels=env)
    caster = RayCaster(hull)
    for view, cam in enumerate(cams):
        origins, dirs = pixel_rays(cam)
        hits = caster.intersect(origins, dirs)
        hit, points, normals = hits.hit, hits.points, hits.shading_towards(dirs)
        matrix = transport_matrix(caster, points[hit], normals[hit], small.shape[1], small.shape[0])
        ours = matrix @ shift_columns(small, ROTATION)[0].reshape(-1, 3)
        reference = renderer.render_numpy(view).reshape(-1, 3)[hit]
        ratio = ours.sum(0) / reference.sum(0)
        flipped = matrix @ shift_columns(small, -ROTATION)[0].reshape(-1, 3)
        corr = np.corrcoef(ours.sum(1), reference.sum(1))[0, 1]
        print(f"view {view}: mean ratio {np.round(ratio, 3)}, correlation {corr:.3f}, "
              f"with the opposite rotation {np.corrcoef(flipped.sum(1), reference.sum(1))[0, 1]:.3f}")
        assert np.all(np.abs(ratio - 1) < 0.05)
        assert corr > 0.85
        assert np.abs(flipped - reference).mean() > 1.5 * np.abs(ours - reference).mean()


def test_camera_response_from_a_visible_background(scene, tmp_path):
    """Frames showing the map behind the object, taken with exposure 0.8 and a warm white
    balance, of an object of albedo 0.3: the background fixes the response and the strength."""
    from backend.capture.images import write_image
    from backend.capture.model import Capture, Frame
    from backend.geometry.mesh import load_mesh
    from backend.render.fields import ConstantField
    from backend.render.scene import RenderSettings, SceneRenderer

    capture, hull, env = scene
    balance, exposure, albedo = np.array([1.15, 1.0, 0.85]), 0.8, 0.3
    mesh = load_mesh(capture.root / "gt" / "mesh.ply")
    cams = [f.camera for f in capture.frames]
    renderer = SceneRenderer(mesh, ConstantField(albedo, 0.0, 0.5), cams, [[] for _ in cams],
                             Environment(Path("env"), STRENGTH, ROTATION), RenderSettings(spp=64, max_depth=3,
                                                                                       hide_emitters=False),
                             env_pixels=env)
    frames = []
    for i, f in enumerate(capture.frames):
        image = tmp_path / f"{f.name}.png"
        write_image(image, renderer.render_numpy(i, seed=i) * exposure * balance)
        frames.append(Frame(f.name, image, f.camera, mask=f.mask))
    shot = Capture(tmp_path, frames, Environment(capture.environment.path))
    alignment = align_lighting(shot, hull, env, AlignConfig())
    response = alignment.response
    implied = 0.5 * np.asarray(alignment.gains) / (alignment.strength * np.asarray(response.white_balance))
    print(f"rotation {alignment.rotation_z_deg:.2f}, strength {alignment.strength:.3f} (truth "
          f"{exposure * STRENGTH * balance.mean():.3f}), white balance {np.round(response.white_balance, 3)} "
          f"(truth {np.round(balance / balance.mean(), 3)}), implied albedo {np.round(implied, 3)}, "
          f"background {alignment.background.provenance()}")
    assert alignment.scale_from == "background" and response.provenance == "estimated"
    assert _angle_error(alignment.rotation_z_deg, ROTATION) < 5.0
    assert np.allclose(response.white_balance, balance / balance.mean(), rtol=0.03)
    assert abs(alignment.strength / (exposure * STRENGTH * balance.mean()) - 1) < 0.10
    assert np.allclose(implied, albedo, rtol=0.10)


def test_the_background_breaks_a_near_tie_of_the_shading(scene, tmp_path):
    """Two equal lamps on opposite sides light the object alike at the true rotation and half
    a turn from it; its albedo (brighter on the side the wrong rotation would light) tips the
    constant-albedo shading fit to the wrong one. The frames' background (the map's dim,
    asymmetric surroundings) decides between the tied shading minima."""
    from backend.capture.images import write_image
    from backend.capture.model import Capture, Frame
    from backend.geometry.mesh import load_mesh
    from backend.render.scene import RenderSettings, SceneRenderer
    from backend.render.views import display_field

    capture, hull, _ = scene
    h, w = 64, 128
    v, u = np.mgrid[:h, :w] + 0.5
    env = np.zeros((h, w, 3), np.float32)
    env[...] = (0.02 + 0.08 * (u / w))[..., None] * np.array([1.0, 0.8, 0.6], np.float32)  # dim, one-sided
    for centre in (0.25 * w, 0.75 * w):  # two equal lamps half a turn apart, 30 degrees up
        env[(u - centre) ** 2 + (v - h / 3) ** 2 < 16] = 40.0
    path = tmp_path / "lamps.exr"
    write_image(path, env)
    mesh = load_mesh(capture.root / "gt" / "mesh.ply")
    cams = [f.camera for f in capture.frames]
    a = np.radians(ROTATION)
    side = mesh.vertices[:, :2] @ np.array([np.cos(a), -np.sin(a)])  # along the lamps' axis
    mesh.vertex_colors = np.repeat(np.where(side > 0, 0.15, 0.8)[:, None], 3, 1).astype(np.float32)
    mesh.attributes = {"specular": np.zeros(mesh.n_vertices, np.float32),
                       "roughness": np.full(mesh.n_vertices, 0.5, np.float32)}
    renderer = SceneRenderer(mesh, display_field(mesh), cams, [[] for _ in cams],
                             Environment(path, 1.0, ROTATION), RenderSettings(spp=32, max_depth=2, hide_emitters=False),
                             env_pixels=env)
    frames = []
    for i, f in enumerate(capture.frames):
        image = tmp_path / f"{f.name}.png"
        write_image(image, renderer.render_numpy(i, seed=i))
        frames.append(Frame(f.name, image, f.camera, mask=f.mask))
    alignment = align_lighting(Capture(tmp_path, frames, Environment(path)), hull, env, AlignConfig())
    print(f"rotation {alignment.rotation_z_deg:.2f}, ties {alignment.ties}")
    assert _angle_error(alignment.rotation_z_deg, ROTATION) < 5.0
    assert len(alignment.ties) >= 2 and sum(t.get("chosen", False) for t in alignment.ties) == 1
    assert alignment.provenance()["ties"] == alignment.ties
