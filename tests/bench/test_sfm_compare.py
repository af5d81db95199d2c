"""bench sfm's pose comparison: a similarity away is no error; a turned camera is its angle."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from backend.bench.sfm import OPENCV_TO_OPENGL, compare


def ring(n: int = 12) -> dict[str, np.ndarray]:
    out = {}
    for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False)):
        c2w = np.eye(4)
        c2w[:3, :3] = Rotation.from_euler("zx", [a + np.pi / 2, np.radians(70)]).as_matrix()
        c2w[:3, 3] = [3 * np.cos(a), 3 * np.sin(a), 1.0]
        out[f"{i:04d}"] = c2w
    return out


def as_sfm(c2w: np.ndarray, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The 3x4 OpenCV world-to-camera pose of camera ``c2w`` in the world x -> s R x + t."""
    rot = R @ c2w[:3, :3] @ OPENCV_TO_OPENGL  # camera-to-world, OpenCV axes
    centre = s * R @ c2w[:3, 3] + t
    return np.hstack([rot.T, (-rot.T @ centre)[:, None]])


def test_similarity_is_no_error_and_a_turned_camera_is_its_angle():
    truth = ring()
    R, t = Rotation.from_euler("xyz", [20, -40, 75], degrees=True).as_matrix(), np.array([0.3, -2.0, 5.0])
    poses = {n: as_sfm(m, 0.37, R, t) for n, m in truth.items()}
    figures = compare(poses, truth)
    assert figures["compared"] == 12
    assert figures["centre_error_pct"]["max"] < 1e-6 and figures["rotation_error_deg"]["max"] < 1e-4
    turned = dict(truth)
    turned["0003"] = truth["0003"].copy()
    turned["0003"][:3, :3] = turned["0003"][:3, :3] @ Rotation.from_euler("y", 3, degrees=True).as_matrix()
    poses["0003"] = as_sfm(turned["0003"], 0.37, R, t)
    figures = compare(poses, truth)
    assert abs(figures["rotation_error_deg"]["max"] - 3.0) < 1e-3
