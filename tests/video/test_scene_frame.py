"""Scene frame: an SfM world levelled (Z up), centred and scaled from cameras and masks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.capture.model import CV_TO_GL, Camera
from backend.video.scene_frame import scene_frame

SIZE, F = 96, 110.0
HALF = np.array([0.5, 0.3, 0.2])  # the object: a 1 x 0.6 x 0.4 box, its up is +z
WORLD = Rotation.from_euler("xyz", [40, -25, 70], degrees=True).as_matrix()  # SfM world <- object
SCALE, OFFSET = 7.0, np.array([3.0, -2.0, 5.0])


def _look_at(eye, up) -> np.ndarray:
    """Camera-to-world (OpenGL axes) at ``eye`` looking at the origin, image up near ``up``."""
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(right, forward), -forward, eye
    return m


def _silhouette(camera: Camera) -> np.ndarray:
    """Pixels whose ray (in the SfM world) passes through the box."""
    v, u = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1).reshape(-1, 3)
    d = rays @ (camera.camera_to_world @ CV_TO_GL)[:3, :3].T @ WORLD  # into object axes
    o = WORLD.T @ (camera.centre - OFFSET) / SCALE
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-HALF - o) / d, (HALF - o) / d
    near, far = np.fmin(t1, t2).max(1), np.fmax(t1, t2).min(1)
    return (far >= np.maximum(near, 0)).reshape(SIZE, SIZE).astype(np.float32)


def _sfm_points(rng) -> np.ndarray:
    """SfM-like points: on the box's top and sides, and on a ground plane around it (outside
    the masks, to be ignored), in the SfM world."""
    u = rng.uniform(-1, 1, (400, 3)) * HALF
    face = rng.integers(0, 3, 400)  # top, +-x side, +-y side
    u[face == 0, 2] = HALF[2]
    u[face == 1, 0] = np.sign(u[face == 1, 0]) * HALF[0]
    u[face == 2, 1] = np.sign(u[face == 2, 1]) * HALF[1]
    ground = np.c_[rng.uniform(-2, 2, (300, 2)), np.full(300, -HALF[2])]
    ground = ground[(np.abs(ground[:, 0]) > 0.8) | (np.abs(ground[:, 1]) > 0.6)]
    return SCALE * np.vstack([u, ground]) @ WORLD.T + OFFSET


@pytest.mark.parametrize("elevation_deg, with_points", [(30, False), (-3, True), (60, True)])
def test_orbit_is_levelled_centred_and_unit_sized(elevation_deg, with_points):
    # At 30 and -3 degrees the images are upright (their up vectors decide the sign); at 60
    # their up runs along the orbit (rolled 90 degrees), so the cameras being above decides.
    e = np.radians(elevation_deg)
    cameras = []
    for a in np.radians(np.arange(0, 360, 30) + 15):
        eye = 3.0 * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
        up = np.array([0, 0, 1.0]) if elevation_deg < 60 else np.array([-np.sin(a), np.cos(a), 0])
        c2w = _look_at(eye, up)
        c2w[:3, :3] = WORLD @ c2w[:3, :3]
        c2w[:3, 3] = SCALE * WORLD @ eye + OFFSET
        cameras.append(Camera(SIZE, SIZE, F, F, SIZE / 2, SIZE / 2, c2w))
    points = _sfm_points(np.random.default_rng(1)) if with_points else None
    frame = scene_frame(cameras, (_silhouette(c) for c in cameras), points)
    assert frame.size_from == ("sparse points inside the masks" if with_points else "visual hull")
    # Up is the object's up.
    assert (frame.matrix[:3, :3] @ WORLD / frame.scale)[:, 2] @ [0, 0, 1] > 0.999
    # The object is at the origin and 1 across (its diameter, the box's diagonal; the hull is a
    # little larger).
    diagonal = 2 * np.linalg.norm(HALF)
    assert frame.scale * SCALE * diagonal == pytest.approx(1.0, rel=0.08 if with_points else 0.12)
    assert np.linalg.norm(frame.point(OFFSET[None])[0]) < 0.05
    # The first camera is on the -Y side; cameras stay rigid.
    moved = [frame.camera(c) for c in cameras]
    assert moved[0].centre[1] / np.linalg.norm(moved[0].centre[:2]) < -0.99
    for c in moved:
        r = c.camera_to_world[:3, :3]
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-9)
    assert ("cameras above" if elevation_deg == 60 else "image up") in frame.up_from
