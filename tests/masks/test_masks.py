"""Automatic masks: the object region from cameras and points, the bad-input paths of
``capture-from-video`` without masks, and the masks of a rendered orbit against its true masks."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from backend.errors import InputError
from backend.masks import MaskOptions
from backend.masks.cameras import View
from backend.masks.consistency import carve, iou, project_hull
from backend.masks.ground import ground_difference
from backend.masks.region import common_focus, object_region
from tests.helpers import run_cli
from tests.video.media import moving_frames, write_video


def _look_at(eye, target, width=320, height=240, f=300.0) -> View:
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.array([x, y, z])
    return View("v", np.c_[R, -R @ eye], f, f, width / 2, height / 2, width, height, {})


def _ring(n=12, radius=3.0, height=1.0, target=(0.2, -0.1, 0.3)):
    views = []
    for i in range(n):
        a = 2 * np.pi * i / n
        v = _look_at(np.array([radius * np.cos(a), radius * np.sin(a), height]), target)
        v.name = f"{i:02d}"
        views.append(v)
    return views


def _scene_points(seed=0):
    """A ball of radius 0.3 at (0.2, -0.1, 0.3) standing on the ground z = 0 (a textured disc)."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(400, 3))
    ball = np.array([0.2, -0.1, 0.3]) + 0.3 * d / np.linalg.norm(d, axis=1, keepdims=True)
    r, t = 2.0 * np.sqrt(rng.random(1500)), 2 * np.pi * rng.random(1500)
    ground = np.c_[r * np.cos(t), r * np.sin(t), 0.002 * rng.normal(size=1500)]
    return np.concatenate([ball, ground]), len(ball)


def test_the_focus_of_a_ring_is_the_point_it_aims_at():
    focus, spread, miss = common_focus(_ring())
    assert np.allclose(focus, [0.2, -0.1, 0.3], atol=1e-6)
    assert spread > 0.05 and miss < 1e-6


def test_the_region_keeps_the_object_and_leaves_the_ground_out():
    points, n_ball = _scene_points()
    region = object_region(_ring(), points)
    assert region.ground is not None
    assert region.inside[:n_ball].mean() > 0.9  # the ball
    assert region.inside[n_ball:].mean() < 0.01  # not the ground
    assert region.background[n_ball:].mean() > 0.9


def test_parallel_cameras_have_no_object_to_isolate():
    views = [_look_at(np.array([x, -3.0, 1.0]), np.array([x, 0.0, 1.0])) for x in np.linspace(-1, 1, 8)]
    points, _ = _scene_points()
    with pytest.raises(InputError) as err:
        object_region(views, points, where="walk.mp4")
    line = str(err.value)
    assert "no object can be isolated" in line and "--masks" in line and "--object-box" in line


def test_the_visual_hull_of_true_silhouettes_agrees_with_each():
    """Masks drawn from a ball's projection: its carved hull projects back onto every mask."""
    views = _ring(8)
    centre, radius = np.array([0.2, -0.1, 0.3]), 0.3
    masks = {}
    for v in views:
        y, x = np.mgrid[0:v.height, 0:v.width] + 0.5
        cam = v.pose[:, :3] @ centre + v.pose[:, 3]
        d = np.stack([(x - v.cx) / v.fx, (y - v.cy) / v.fy, np.ones_like(x)], -1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        along = d @ cam
        masks[v.name] = (np.sum(cam ** 2) - along ** 2 < radius ** 2).astype(np.float32)
    hull = carve(views, masks, centre - 0.5, centre + 0.5, grid=64, tolerance=0)
    scores = [iou(project_hull(hull, v), masks[v.name]) for v in views]
    assert min(scores) > 0.9
    wrong = dict(masks, **{views[0].name: np.roll(masks[views[0].name], 60, axis=1)})
    hull = carve(views, wrong, centre - 0.5, centre + 0.5, grid=64, tolerance=1)
    assert iou(project_hull(hull, views[0]), wrong[views[0].name]) < 0.5  # the odd one out shows
    # the tolerant hull is looser than each true silhouette, but within the IoU that keeps a frame
    assert min(iou(project_hull(hull, v), masks[v.name]) for v in views[1:]) > MaskOptions().min_iou


def _one_line(proc) -> str:
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.strip().count("\n") == 0 and "Traceback" not in proc.stderr
    return proc.stderr


def test_a_blank_wall_stops_with_one_line_naming_what_to_give(tmp_path):
    rng = np.random.default_rng(0)
    frames = [np.clip(128 + rng.normal(0, 1, (288, 512, 3)), 0, 255).astype(np.uint8) for _ in range(8)]
    video = write_video(tmp_path / "wall.mp4", frames)
    out = tmp_path / "capture"
    line = _one_line(run_cli("capture-from-video", video, "--out", out, "--blur-ratio", 0))
    assert "no object can be isolated" in line and "--masks" in line and "--object-box" in line
    assert str(video) in line
    assert not out.exists()


@pytest.mark.parametrize("option, value, expected", [
    ("--mask-model", "missing.onnx", "mask model not found"),
    ("--mask-model", "NOT_ONNX", "not a model OpenCV can read"),
    ("--object-box", "0,0,0,1,1", "is not six numbers"),
    ("--object-box", "0,0,0,1,-1,1", "is empty"),
])
def test_bad_mask_options_fail_before_any_work(tmp_path, option, value, expected):
    video = write_video(tmp_path / "orbit.mp4", moving_frames(4, 96, 64))
    if value == "NOT_ONNX":
        value = tmp_path / "model.onnx"
        value.write_bytes(b"not a network")
    out = tmp_path / "capture"
    line = _one_line(run_cli("capture-from-video", video, "--out", out, option, value))
    assert expected in line
    assert not out.exists()


def test_masks_of_a_rendered_orbit_match_the_true_masks(tmp_path):
    """The bench's bunny orbit (Cycles): SfM without masks, then the masks (16 frames at 512 px
    register too few views for a consistent hull)."""
    proc = run_cli("bench", "masks", "--out", tmp_path, "--scenes", "bunny", "--frames", "24",
                   "--size", "640x360", "--samples", "4", "--f1-minutes", "0", timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    record = json.loads((Path(os.environ["SFT_RECORDS"]) / "masks.json").read_text())
    (row,) = record["figures"]["rows"]
    assert row["kept"] >= row["frames"] // 3, row
    assert row["mean IoU"] >= 0.9, row


def _texture(x, y):
    """A colour texture of the plane coordinates (smooth enough to sample, varied enough to match)."""
    return np.stack([128 + 90 * np.sin(9 * x) * np.cos(7 * y), 128 + 90 * np.sin(5 * x + 11 * y),
                     128 + 90 * np.cos(13 * x - 3 * y)], -1)


def _plane_image(view: View, height: float) -> np.ndarray:
    """``view``'s image of the textured plane z = ``height`` (ray-plane intersection per pixel)."""
    y, x = np.mgrid[0:view.height, 0:view.width] + 0.5
    R, c = view.pose[:, :3], view.centre
    d = np.stack([(x - view.cx) / view.fx, (y - view.cy) / view.fy, np.ones_like(x)], -1) @ R  # world rays
    t = (height - c[2]) / d[..., 2]
    p = c + t[..., None] * d
    return np.clip(_texture(p[..., 0], p[..., 1]), 0, 255).astype(np.uint8)


def test_the_ground_lines_up_through_its_plane_and_what_stands_off_it_does_not():
    """Neighbours warped through the plane z = 0 match a view of that plane; a surface 0.3 above it
    (an object standing on the ground) differs by its parallax."""
    views = _ring(12, radius=3.0, height=1.5, target=(0.0, 0.0, 0.0))
    plane, centre = np.array([0, 0, 1.0, 0.0]), np.zeros(3)
    for height, expect_ground in ((0.0, True), (0.3, False)):
        images = [_plane_image(v, height) for v in views]
        d = ground_difference(images[0], views[0], [(images[j], views[j]) for j in (1, 11)], plane, centre, 1.0)
        middle = d[60:180, 80:240]  # the frame's centre: every neighbour sees it
        assert np.isfinite(middle).all()
        if expect_ground:
            assert np.median(middle) < 3.0, np.median(middle)
        else:
            assert np.median(middle) > 15.0, np.median(middle)


def test_the_outline_moves_onto_the_frame_s_edge():
    """A mask two pixels off a disc's edge (a noisy red disc on a noisy grey ground) comes back
    onto the edge: GrabCut's band and the guided filter both follow the frame's colours."""
    import bpy  # noqa: F401  (bpy before cv2 in one process)

    from backend.masks.outline import refine_outline

    rng = np.random.default_rng(3)
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w]
    disc = (yy - 60) ** 2 + (xx - 80) ** 2 < 35 ** 2
    rgb = np.where(disc[..., None], [200, 60, 50], [120, 120, 125]) + rng.normal(0, 6, (h, w, 3))
    rgb = np.clip(rgb, 0, 255).astype(np.uint8)
    off = ((yy - 62) ** 2 + (xx - 78) ** 2 < 35 ** 2).astype(np.float32)
    before = iou(off > 0.5, disc)
    after = refine_outline(rgb, off)
    assert after.dtype == np.float32 and set(np.unique(after)) <= {0.0, 1.0}
    assert iou(after > 0.5, disc) > 0.99 > before, (before, iou(after > 0.5, disc))


def test_a_deep_piece_outside_the_other_frames_hull_is_cut_and_a_shallow_one_stays():
    """``trim_outside``: the hull's projection covers the object; a blob reaching 12 px beyond it
    goes, a 3-px sliver along it (the hull's coarseness) stays, the object is untouched."""
    from backend.masks.auto import trim_outside

    hull = np.zeros((80, 120), np.float32)
    hull[20:60, 30:70] = 1
    mask = hull.copy()
    mask[30:50, 70:94] = 1  # a blob 24 px beyond the hull's right edge
    mask[15:20, 35:65] = 1  # a 5-px sliver above it
    out = trim_outside(mask, hull, band=2, depth_px=8.0)
    assert out[20:60, 30:70].all() and out[15:20, 35:65].all()
    assert not out[30:50, 73:94].any()
    assert out.sum() < mask.sum() and set(np.unique(out)) <= {0.0, 1.0}
