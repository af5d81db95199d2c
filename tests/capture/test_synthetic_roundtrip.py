"""Known cameras written in each layout and imported back: same cameras, same silhouettes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from backend.capture.importers import detect, import_any
from backend.capture.importers.colmap import qvec_to_rotation, read_model
from backend.capture.importers.middlebury import Y_UP_TO_Z_UP
from backend.capture.images import read_mask
from backend.capture.model import CV_TO_GL, Camera
from backend.geometry.mesh import load_mesh
from tests.capture import synthetic as syn

MESH = syn.blob()


@pytest.fixture(scope="module")
def truth():
    cams = syn.sphere_cameras()
    return cams, [syn.rasterise(*MESH, c) for c in cams]


def check_round_trip(capture, cams, masks):
    assert len(capture.frames) == len(cams)
    for frame, cam, mask in zip(capture.frames, cams, masks):
        got = frame.camera
        assert (got.width, got.height) == (cam.width, cam.height)
        np.testing.assert_allclose([got.fx, got.fy, got.cx, got.cy], [cam.fx, cam.fy, cam.cx, cam.cy], rtol=1e-7)
        np.testing.assert_allclose(got.camera_to_world, cam.camera_to_world, atol=1e-7)
        assert mask.mean() > 0.05
        assert syn.iou(syn.rasterise(*MESH, got), mask) > 0.95


def test_silhouette_check_has_power(truth):
    """Convention errors an importer could make fail the IoU check or put the object behind."""
    cams, masks = truth
    cam = cams[0]
    moved = lambda m=cam.camera_to_world, cx=cam.cx: Camera(cam.width, cam.height, cam.fx, cam.fy, cx, cam.cy, m)  # noqa: E731
    assert np.all(moved(cam.camera_to_world @ CV_TO_GL).project(MESH[0])[1] < 0)  # OpenCV axes read as OpenGL
    assert syn.iou(syn.rasterise(*MESH, moved(cam.camera_to_world @ np.diag([-1.0, -1, 1, 1]))), masks[0]) < 0.8
    assert syn.iou(syn.rasterise(*MESH, moved(cx=cam.cx + 3)), masks[0]) < 0.95


@pytest.mark.parametrize("variant", ["intrinsics+masks", "angle+alpha"])
def test_nerf(tmp_path, truth, variant):
    cams, masks = truth
    if variant == "angle+alpha":  # camera_angle_x only: square pixels, principal point at the centre
        cams = [Camera(c.width, c.height, c.fx, c.fx, c.width / 2, c.height / 2, c.camera_to_world) for c in cams]
        masks = [syn.rasterise(*MESH, c) for c in cams]
    path = syn.write_transforms(tmp_path, cams, masks, angle_only=variant == "angle+alpha",
                                rgba=variant == "angle+alpha", mask_folder=variant == "intrinsics+masks")
    assert detect(tmp_path) == "NeRF / instant-ngp"
    capture = import_any(path)
    check_round_trip(capture, cams, masks)
    for frame, mask in zip(capture.frames, masks):
        assert frame.mask is not None
        assert np.array_equal(read_mask(frame.mask) > 0.5, mask)
    assert (capture.frames[0].mask == capture.frames[0].image) == (variant == "angle+alpha")


def test_nerf_lights_and_environment(tmp_path, truth):
    cams, masks = truth
    path = syn.write_transforms(tmp_path, cams[:2], masks[:2])
    doc = json.loads(path.read_text())
    doc["frames"][1]["lights"] = [{"type": "point", "position": [0, 1, 2], "intensity_w_per_sr": [3, 4, 5]}]
    doc["environment"] = {"path": "sky.hdr", "strength": 2.0, "rotation_z_deg": 45}
    path.write_text(json.dumps(doc))
    capture = import_any(path)
    assert not capture.frames[0].lights
    light = capture.frames[1].lights[0]
    assert light.position.tolist() == [0, 1, 2] and light.intensity.tolist() == [3, 4, 5]
    env = capture.environment
    assert (env.path, env.strength, env.rotation_z_deg) == (tmp_path / "sky.hdr", 2.0, 45.0)


@pytest.mark.parametrize("kind", ["text", "binary"])
def test_colmap(tmp_path, truth, kind):
    cams, masks = truth
    model = tmp_path / "sparse" / "0"
    points = np.random.default_rng(1).normal(size=(20, 3))
    (syn.write_colmap_text if kind == "text" else syn.write_colmap_binary)(model, cams, points)
    frames = tmp_path / ("images" if kind == "text" else "elsewhere")  # binary: frames folder given
    for i, m in enumerate(masks):
        syn.save_png(frames / f"{i:03d}.png", m)
    assert detect(tmp_path) == "COLMAP"
    capture = import_any(tmp_path, workdir=tmp_path / "work", images=None if kind == "text" else frames)
    check_round_trip(capture, cams, masks)
    assert [f.image for f in capture.frames] == [frames / f"{i:03d}.png" for i in range(len(cams))]
    cloud = load_mesh(capture.points)
    np.testing.assert_allclose(cloud.vertices, points, atol=1e-6)  # float32 PLY
    assert cloud.n_faces == 0
    assert import_any(model, images=frames).points is None  # nothing derived without a work folder


@pytest.mark.parametrize("kind", ["text", "binary"])
def test_colmap_reader_agrees_with_pycolmap(tmp_path, truth, kind):
    """pycolmap reads our hand-written model, writes it the other way, and we read that back."""
    pycolmap = pytest.importorskip("pycolmap")
    cams, _ = truth
    points = np.random.default_rng(2).normal(size=(5, 3))
    (syn.write_colmap_text if kind == "text" else syn.write_colmap_binary)(tmp_path / "a", cams, points)
    rec = pycolmap.Reconstruction(str(tmp_path / "a"))
    assert rec.num_reg_images() == len(cams) and rec.num_points3D() == len(points)
    (tmp_path / "b").mkdir()
    (rec.write_binary if kind == "text" else rec.write_text)(str(tmp_path / "b"))
    ours_a, ours_b = read_model(tmp_path / "a"), read_model(tmp_path / "b")
    for cam_a, cam_b in zip(sorted(ours_a[0].items()), sorted(ours_b[0].items())):
        assert cam_a[1][:3] == cam_b[1][:3]
        np.testing.assert_allclose(cam_a[1][3], cam_b[1][3])
    for image in rec.images.values():
        name, q, t, cam_id = ours_b[1][image.image_id]
        assert name == image.name and cam_id == image.camera_id
        R = image.cam_from_world().rotation.matrix()
        np.testing.assert_allclose(qvec_to_rotation(q), R, atol=1e-9)
        np.testing.assert_allclose(t, image.cam_from_world().translation, atol=1e-9)
    np.testing.assert_allclose(np.sort(ours_b[2][0], 0), np.sort(points, 0), atol=1e-9)


def test_idr(tmp_path, truth):
    cams, masks = truth
    syn.write_idr(tmp_path, cams, masks)
    assert detect(tmp_path) == "IDR / NeuS"
    capture = import_any(tmp_path)
    check_round_trip(capture, cams, masks)  # views without an image were skipped
    assert [f.mask.name for f in capture.frames] == [f"{i:03d}.png" for i in range(len(cams))]


def test_middlebury(tmp_path, truth):
    cams, masks = truth
    syn.write_middlebury(tmp_path, cams, masks, Y_UP_TO_Z_UP)
    assert detect(tmp_path) == "Middlebury"
    capture = import_any(tmp_path / "obj_par.txt")
    check_round_trip(capture, cams, masks)
    assert all(f.mask is None for f in capture.frames)


def test_alicevision(tmp_path, truth):
    cams, masks = truth
    syn.write_alicevision(tmp_path, cams, masks)
    assert detect(tmp_path) == "AliceVision"
    check_round_trip(import_any(tmp_path), cams, masks)
