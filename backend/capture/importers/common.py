"""Pieces the importers share: OpenCV-style cameras, projection matrices, file look-up."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.linalg

from ...errors import InputError, require
from ..format import check_pose
from ..model import CV_TO_GL, Camera

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".hdr", ".tif", ".tiff", ".bmp")


def opencv_camera(K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int, height: int,
                  pixel_offset: float, distortion: dict | None = None) -> Camera:
    """Our camera from OpenCV intrinsics K and world-to-camera [R|t] (x right, y down, z forward).

    ``pixel_offset`` is added to the principal point: 0.5 for K matrices with pixel centres at
    integers (OpenCV, projection matrices), 0 for COLMAP's corner-based convention (ours)."""
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = -R.T @ t
    return Camera(int(width), int(height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]) + pixel_offset,
                  float(K[1, 2]) + pixel_offset, c2w @ CV_TO_GL,
                  {k: float(v) for k, v in (distortion or {}).items() if v})


def decompose_projection(P: np.ndarray, path, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split a 3x4 projection P ~ K[R|t] into K (K[2,2] = 1, positive focal lengths), R, t."""
    P = np.asarray(P, dtype=np.float64)[:3]
    require(bool(np.all(np.isfinite(P))), path, f"{where}: projection matrix contains NaN or Inf",
            "re-export the cameras")
    M = P[:, :3]
    det = np.linalg.det(M)
    require(abs(det) > 1e-12 * max(1.0, np.abs(M).max()) ** 3, path,
            f"{where}: projection matrix is singular", "re-export the cameras")
    if det < 0:  # P is defined up to scale; pick the sign that makes det(R) = +1
        P = -P
        M = P[:, :3]
    K, R = scipy.linalg.rq(M)
    signs = np.diag(np.sign(np.diag(K)))
    K, R = K @ signs, signs @ R
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t


def projection_camera(P: np.ndarray, width: int, height: int, path, where: str) -> Camera:
    """Our camera from a projection matrix K[R|t] with integer pixel centres (skew dropped)."""
    K, R, t = decompose_projection(P, path, where)
    camera = opencv_camera(K, R, t, width, height, pixel_offset=0.5)
    check_pose(camera.camera_to_world, path, where)
    return camera


def transformed(camera: Camera, world: np.ndarray) -> Camera:
    """The camera after a rigid change of world frame ``world`` (4x4, new <- old)."""
    return Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
                  world @ camera.camera_to_world, dict(camera.distortion))


def find_image(folder: Path, stem: str) -> Path | None:
    """The image file ``folder/stem.<any image suffix>``, or None."""
    for suffix in IMAGE_SUFFIXES:
        for candidate in (folder / (stem + suffix), folder / (stem + suffix.upper())):
            if candidate.is_file():
                return candidate
    return None


def image_files(folder: Path) -> list[Path]:
    """Image files in ``folder``, sorted by name."""
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def read_text(path: Path) -> str:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(path, f"cannot read ({err.__class__.__name__})", "check the file") from err


def numbers(values, path: Path, where: str) -> np.ndarray:
    """Parse a list of numbers, naming the file on failure."""
    try:
        return np.asarray([float(v) for v in values], dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputError(path, f"{where}: expected numbers", "fix or re-export the file") from err
