"""The capture model's conventions hold in the renderer: cameras, principal point, environment."""

import numpy as np
import pytest

from backend import variant

variant.choose()
import mitsuba as mi  # noqa: E402

from backend.capture import load_capture  # noqa: E402
from backend.capture.images import read_mask  # noqa: E402
from backend.capture.model import Camera, Environment  # noqa: E402
from backend.geometry.mesh import load_mesh  # noqa: E402
from backend.render import scene as render_scene  # noqa: E402
from backend.synth.layout import look_at  # noqa: E402


def _render(scene_dict, camera, spp=16):
    scene = mi.load_dict({"type": "scene", **scene_dict})
    sensor = mi.load_dict(render_scene.sensor_dict(camera, spp))
    return np.array(mi.render(scene, sensor=sensor, spp=spp))


@pytest.mark.parametrize("cx, cy", [(32.0, 24.0), (41.0, 17.5), (20.0, 30.0)])
def test_point_projects_where_camera_model_says(cx, cy):
    camera = Camera(64, 48, 50.0, 50.0, cx, cy, look_at([0.3, -3.0, 0.4], [0.0, 0.0, 0.2]))
    point = np.array([0.2, 0.1, 0.5])
    img = _render({"integrator": {"type": "aov", "aovs": "d:depth"},
                   "ball": {"type": "sphere", "center": point.tolist(), "radius": 0.02}}, camera, 64)
    ys, xs = np.nonzero(img[..., 0] > 0)
    (u, v), depth = camera.project(point[None])[0][0], camera.project(point[None])[1][0]
    assert depth > 0
    assert abs(xs.mean() + 0.5 - u) < 0.35 and abs(ys.mean() + 0.5 - v) < 0.35


def _blender_lookup_uv(d, rotation_deg):
    """docs/capture-format.md: u = 0.5 - atan2(d'y, d'x)/2pi, v = acos(d'z)/pi, d' = Rz(a) d."""
    a = np.radians(rotation_deg)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    dd = rz @ d
    return (0.5 - np.arctan2(dd[1], dd[0]) / (2 * np.pi)) % 1.0, np.arccos(np.clip(dd[2], -1, 1)) / np.pi


@pytest.mark.parametrize("rotation", [0.0, 73.0])
@pytest.mark.parametrize("direction", [[1, 0, 0], [0, 1, 0], [0.3, -0.8, 0.5], [-0.6, -0.2, -0.7]])
def test_environment_direction_matches_blender_mapping(tmp_path, rotation, direction):
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    width, height = 256, 128
    u, v = _blender_lookup_uv(d, rotation)
    env = np.full((height, width, 3), 0.01, np.float32)
    x, y = int(u * width) % width, min(int(v * height), height - 1)
    env[max(y - 2, 0):y + 3, [(x + k) % width for k in range(-2, 3)]] = [50.0, 10.0, 1.0]
    environment = Environment(tmp_path / "unused.exr", strength=2.0, rotation_z_deg=rotation)
    camera = Camera(33, 33, 60.0, 60.0, 16.5, 16.5, look_at([0, 0, 0], d, up=[0, 0.1, 1]))
    img = _render({"integrator": {"type": "path", "max_depth": 1},
                   "env": render_scene.environment_dict(environment, env)}, camera, 4)
    y_hot, x_hot = np.unravel_index(np.argmax(img[..., 0]), img.shape[:2])
    assert abs(y_hot - 16) <= 2 and abs(x_hot - 16) <= 2
    assert img[..., 0].max() > 40  # strength 2 x radiance 50, partly filtered


def _splat_coverage(mesh, camera, supersample=4, samples=600_000, seed=0):
    """Per-pixel covered fraction, by splatting dense surface samples at a higher resolution."""
    fine = _splat_mask(mesh, camera.scaled(supersample), samples, seed)
    h, w = camera.height, camera.width
    return fine.reshape(h, supersample, w, supersample).mean(axis=(1, 3))


def _splat_mask(mesh, camera, samples, seed):
    rng = np.random.default_rng(seed)
    tri = mesh.vertices[mesh.faces]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    idx = rng.choice(len(tri), samples, p=area / area.sum())
    r1, r2 = rng.random(samples), rng.random(samples)
    s = np.sqrt(r1)
    pts = (1 - s)[:, None] * tri[idx, 0] + (s * (1 - r2))[:, None] * tri[idx, 1] + (s * r2)[:, None] * tri[idx, 2]
    uv, depth = camera.project(pts)
    ok = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    mask = np.zeros((camera.height, camera.width), bool)
    mask[uv[ok, 1].astype(int), uv[ok, 0].astype(int)] = True
    return mask


def test_synthetic_masks_agree_with_projected_ground_truth(tiny_capture):
    capture = load_capture(tiny_capture)
    mesh = load_mesh(capture.root / capture.ground_truth["mesh"])
    for frame in capture.frames:
        projected = _splat_coverage(mesh, frame.camera)
        rendered = read_mask(frame.mask)
        iou = np.minimum(projected, rendered).sum() / np.maximum(projected, rendered).sum()
        assert iou > 0.95, f"frame {frame.name}: IoU {iou:.3f}"
