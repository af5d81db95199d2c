"""The importers on the real captures in ../shared/data, with their conventions proved
against the captures' own masks (or masks derived from the images)."""

from __future__ import annotations

import json

import numpy as np
from scipy import ndimage

from backend.capture.images import read_mask
from backend.capture.importers import import_any
from backend.capture.importers.middlebury import Y_UP_TO_Z_UP
from backend.capture.validate import validate_capture
from tests.helpers import shared_data

# Middlebury README: tight bounding box of the dino, in the source (Y-up) frame.
DINO_BOX = np.array([[-0.061897, -0.018874, -0.057845], [0.010897, 0.068227, 0.015495]])


def inside(mask: np.ndarray, uv: np.ndarray, outside=True) -> np.ndarray:
    """Mask value at pixel positions; positions outside the frame count as ``outside``."""
    ij = np.floor(uv).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < mask.shape[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < mask.shape[0])
    out = np.full(len(uv), outside)
    out[ok] = mask[ij[ok, 1], ij[ok, 0]]
    return out


def visual_hull_ious(frames, masks, lo, hi, n=56, cell=8):
    """Carve a grid with every mask, project the hull back: IoU with each mask (at 1/cell size)."""
    axes = [np.linspace(lo[i], hi[i], n) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    keep = np.ones(len(grid), bool)
    for frame, mask in zip(frames, masks):
        keep &= inside(mask, frame.camera.project(grid)[0])
    hull, ious = grid[keep], []
    assert len(hull) > 100
    for frame, mask in zip(frames, masks):
        h, w = mask.shape[0] // cell, mask.shape[1] // cell
        ij = np.floor(frame.camera.project(hull)[0] / cell).astype(int)
        ok = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
        splat = np.zeros((h, w), bool)
        splat[ij[ok, 1], ij[ok, 0]] = True
        splat = ndimage.binary_closing(splat, iterations=2)
        small = mask[:h * cell, :w * cell].reshape(h, cell, w, cell).mean((1, 3)) > 0.5
        ious.append((splat & small).sum() / (splat | small).sum())
    return hull, np.array(ious)


def test_fox_transforms():
    folder = shared_data("captures", "fox_instant_ngp")
    doc = json.loads((folder / "transforms.json").read_text())
    capture = import_any(folder)
    validate_capture(capture)
    assert len(capture.frames) == len(doc["frames"]) == 67
    cam = capture.frames[0].camera
    assert (cam.width, cam.height) == (1080, 1920)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (doc["fl_x"], doc["fl_y"], doc["cx"], doc["cy"])  # no +0.5
    assert cam.distortion == {k: doc[k] for k in ("k1", "k2", "p1", "p2")}
    np.testing.assert_array_equal(cam.camera_to_world, doc["frames"][0]["transform_matrix"])
    assert capture.frames[0].mask is None  # JPEG frames, no masks folder
    # A handheld capture of one object: every camera looks at the common point, upright in a Z-up world.
    centre, _ = capture.bounds_hint()
    for frame in capture.frames:
        to_centre = centre - frame.camera.centre
        assert frame.camera.forward @ to_centre / np.linalg.norm(to_centre) > 0.9
        assert frame.camera.camera_to_world[2, 1] > 0.8  # image up is world +Z


def test_dtu_cameras_match_masks():
    folder = shared_data("captures", "dtu_scan65")
    capture = import_any(folder)
    validate_capture(capture)
    names = [f.name for f in capture.frames]
    assert names == [f"{i:06d}" for i in range(0, 49, 4)]  # only 13 of the 49 views have images
    assert [f.mask.name for f in capture.frames] == [f"{i:03d}.png" for i in range(0, 49, 4)]
    masks = [read_mask(f.mask) > 0.5 for f in capture.frames]
    for frame, mask in zip(capture.frames, masks):
        assert 0.25 < mask.mean() < 0.45
        assert inside(mask, frame.camera.project(np.zeros((1, 3)))[0], outside=False)[0]  # sphere centre
        assert abs(frame.camera.fx / frame.camera.fy - 1) < 0.01
    # Cameras and masks agree with one another: the visual hull reprojects onto every mask.
    ball = np.ones(3)
    _, ious = visual_hull_ious(capture.frames, masks, -ball, ball)
    assert ious.min() > 0.9, ious


def test_dino_derived_masks_and_z_up(tmp_path):
    folder = shared_data("captures", "middlebury_dinoSparseRing")
    assert all(f.mask is None for f in import_any(folder).frames)  # nothing derived without a work folder
    capture = import_any(folder / "dinoSR_par.txt", workdir=tmp_path)
    validate_capture(capture)
    assert len(capture.frames) == 16
    assert all(f.mask.parent == tmp_path / "masks" for f in capture.frames)
    assert "dinoSR0006" not in capture.provenance["good_silhouettes"]
    # Z-up: the ring of cameras turns about world Z, and the dino is tallest along Z.
    centres = np.array([f.camera.centre for f in capture.frames])
    normal = np.linalg.svd(centres - centres.mean(0))[2][2]
    assert abs(normal[2]) > 0.99
    box = DINO_BOX @ Y_UP_TO_Z_UP[:3, :3].T
    lo, hi = box.min(0), box.max(0)
    assert np.argmax(hi - lo) == 2
    good = [f for f in capture.frames if f.name in capture.provenance["good_silhouettes"]]
    masks = [read_mask(f.mask) > 0.5 for f in good]
    for frame, mask in zip(good, masks):
        assert 0.05 < mask.mean() < 0.7
        assert inside(mask, frame.camera.project(((lo + hi) / 2)[None])[0], outside=False)[0]
    pad = 0.15 * (hi - lo)
    hull, ious = visual_hull_ious(good, masks, lo - pad, hi + pad, cell=4)
    assert ious.min() > 0.9, ious
    # The hull encloses the object: it spans the README's bounding box (to a grid cell) and,
    # carved from one ring of views, overshoots it by at most 2 cm (the dino is 8.7 cm tall).
    assert np.all(hull.min(0) <= lo + 0.003) and np.all(hull.max(0) >= hi - 0.003)
    assert np.all(hull.min(0) >= lo - 0.02) and np.all(hull.max(0) <= hi + 0.02)


def test_alicevision_buddha():
    folder = shared_data("captures", "alicevision_buddha")
    capture = import_any(folder)
    validate_capture(capture)
    assert [f.name for f in capture.frames] == ["00006", "00042", "00052", "00060"]
    P = np.loadtxt(folder / "P" / "00006_P.txt")
    for frame in capture.frames:
        cam = frame.camera
        assert (cam.width, cam.height) == (2736, 1540)
        assert abs(cam.fx - 1861) < 10 and abs(cam.fx / cam.fy - 1) < 1e-3
        assert abs(cam.cx - 1369) < 10 and abs(cam.cy - 774) < 10
    # The camera reproduces the projection matrix it came from (pixel centres shifted by 0.5).
    points = np.random.default_rng(0).normal(size=(10, 3)) + capture.bounds_hint()[0]
    uvw = np.c_[points, np.ones(10)] @ P.T
    np.testing.assert_allclose(capture.frames[0].camera.project(points)[0], uvw[:, :2] / uvw[:, 2:] + 0.5, atol=1e-6)
