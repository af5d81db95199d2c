"""SfM points + screened Poisson: a surface through the capture's sparse point cloud.

Outliers (points far from their neighbours, and points outside the masks when there are
masks) are dropped; normals are estimated from neighbours when the file has none and
oriented away from the cloud's centre (sound for the roughly star-shaped objects a
turntable-style capture shows); a shallow Poisson octree keeps the surface smooth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ...capture.images import read_mask
from ...capture.model import Capture
from ...errors import InputError, require
from ..mesh import Mesh
from ..poisson import poisson
from ..simplify import simplify

MIN_POINTS = 50


def read_points(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (N, 3) and normals (N, 3) or None, from a PLY/OBJ/XYZ point cloud."""
    import pymeshlab

    if not Path(path).is_file():
        raise InputError(path, "point cloud not found", "check 'points' in capture.json")
    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except Exception as err:
        raise InputError(path, f"cannot read point cloud ({err})".replace("\n", " "), "write it as PLY") from err
    m = ms.current_mesh()
    points = m.vertex_matrix()
    normals = m.vertex_normal_matrix()
    if normals.shape != points.shape or not np.any(np.linalg.norm(normals, axis=1) > 0.5):
        normals = None
    return points, normals


def drop_outliers(points: np.ndarray, k: int = 8, sigmas: float = 2.5) -> np.ndarray:
    """Keep points whose mean distance to their k nearest neighbours is not unusually large."""
    d, _ = cKDTree(points).query(points, k=min(k + 1, len(points)))
    mean = d[:, 1:].mean(1)
    return mean <= np.median(mean) + sigmas * mean.std()


def inside_masks(capture: Capture, points: np.ndarray) -> np.ndarray:
    keep = np.ones(len(points), bool)
    for frame in capture.frames:
        mask = read_mask(frame.mask) > 0.5
        uv, depth = frame.camera.project(points)
        h, w = mask.shape
        px = np.floor(uv).astype(np.int64)
        inframe = (depth > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        hit = np.zeros(len(points), bool)
        hit[inframe] = mask[px[inframe, 1], px[inframe, 0]]
        keep &= hit | ~inframe
    return keep


def estimate_normals(points: np.ndarray, k: int = 16) -> np.ndarray:
    """PCA normals from k neighbours, oriented away from the cloud's centre."""
    _, idx = cKDTree(points).query(points, k=min(k, len(points)))
    nb = points[idx] - points[idx].mean(1, keepdims=True)
    _, _, vt = np.linalg.svd(nb, full_matrices=False)
    normals = vt[:, -1]
    flip = np.einsum("ij,ij->i", normals, points - np.median(points, 0)) < 0
    normals[flip] *= -1
    return normals


def points_mesh(capture: Capture, faces: int = 5000, depth: int = 7) -> Mesh:
    require(capture.points is not None, capture.root, "the capture has no point cloud ('points')",
            "run structure from motion first, or choose --init carve, sphere or a mesh file")
    points, normals = read_points(capture.points)
    keep = drop_outliers(points) if len(points) > MIN_POINTS else np.ones(len(points), bool)
    if capture.has_masks:
        keep &= inside_masks(capture, points)
    points = points[keep]
    require(len(points) >= MIN_POINTS, capture.points,
            f"only {len(points)} usable points (at least {MIN_POINTS} needed)",
            "use a denser reconstruction, or choose --init carve or sphere")
    normals = normals[keep] if normals is not None else estimate_normals(points)
    return simplify(poisson(points, normals, depth=depth), faces)
