"""The scene frame: SfM's arbitrary world turned into Blender's, Z up, object at the origin,
1 unit across.

- **Size and centre**: the sparse SfM points inside every mask that sees them (the visual
  hull), or where there are too few, the hull's voxels. The centre of their bounding box in
  the levelled frame goes to the origin, and their diameter (largest distance between two
  of them) is scaled to 1. (The hull alone is too tall: nothing carves below the object,
  nor above it when no view looks from the side.)
- **Up**: a phone orbit is roughly level, so the normal of the plane through the camera
  centres is up. Its sign is the side the images' up vectors point to; when they lie in
  the plane (cameras looking along the axis), the side the cameras are on (above the object).
  When the centres lie on a line, the mean image up vector is used instead.
- **Heading**: turned about Z so the first camera sits on the -Y side looking towards +Y,
  like Blender's front view."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..capture.model import Camera, Capture, Frame
from ..geometry.init.hull import (
    LEVEL,
    HullConfig,
    MaskView,
    field_on_box,
    hull_box,
    sample,
)

HULL_MASK_SIZE = 480  # masks are box-filtered to about this longer side for carving
HULL_GRID = 64
MIN_POINTS = 50
PLANAR_SPREAD = 0.2  # second / first singular value of the centres below which they form a line
CLEAR_UP = 0.2  # |mean image-up . normal| above which the images decide the up sign


@dataclass
class SceneFrame:
    matrix: np.ndarray  # 4x4 similarity, new world <- SfM world
    scale: float  # new units per SfM unit
    up_from: str  # what decided the up axis
    size_from: str  # what the centre and size come from

    def point(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, np.float64) @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def camera(self, camera: Camera) -> Camera:
        """``camera`` (OpenGL axes, camera-to-world) in the new world: rotated, moved, not scaled."""
        c2w = np.eye(4)
        c2w[:3, :3] = self.matrix[:3, :3] @ camera.camera_to_world[:3, :3] / self.scale
        c2w[:3, 3] = self.point(camera.camera_to_world[:3, 3][None])[0]
        return Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, c2w,
                      dict(camera.distortion))


def _box_filter(mask: np.ndarray, k: int) -> np.ndarray:
    h, w = mask.shape[0] // k * k, mask.shape[1] // k * k
    return mask[:h, :w].reshape(h // k, k, w // k, k).mean((1, 3))


def _views(cameras: list[Camera], masks: Iterable[np.ndarray]) -> list[MaskView]:
    """Mask views reduced to about HULL_MASK_SIZE px (masks may come from a generator)."""
    views = []
    for camera, mask in zip(cameras, masks):
        k = max(1, max(mask.shape) // HULL_MASK_SIZE)
        small = _box_filter(np.asarray(mask, np.float32), k)
        views.append(MaskView(Camera(small.shape[1], small.shape[0], camera.fx / k, camera.fy / k, camera.cx / k,
                                     camera.cy / k, camera.camera_to_world), small))
    return views


def object_points(cameras: list[Camera], masks: Iterable[np.ndarray], points: np.ndarray | None = None,
                  where: Path | None = None) -> tuple[np.ndarray, str]:
    """Points that stand for the object, and which they are: the SfM points inside the visual
    hull when there are MIN_POINTS of them (the hull alone runs on below the object and above
    it where no view looks from the side), else the centres of the hull's voxels (largest
    part). Cameras are ideal pinholes; masks, one per camera, are (H, W) in [0, 1]."""
    views = _views(cameras, masks)
    config = HullConfig()
    probe = Capture(root=Path(where or "."), frames=[Frame(str(i), Path(), v.camera) for i, v in enumerate(views)])
    lo, hi = hull_box(probe, views, config)
    if points is not None and len(points):
        inside = points[sample(views, np.asarray(points, np.float64), config) > LEVEL]
        if len(inside) >= MIN_POINTS:
            return inside, "sparse points inside the masks"
    field = field_on_box(views, lo, hi, HULL_GRID, config)
    return field.points()[field.largest_part().ravel()], "visual hull"


def up_axis(cameras: list[Camera], pivot: np.ndarray) -> tuple[np.ndarray, str]:
    """Unit up vector in the cameras' world and what decided it."""
    centres = np.array([c.centre for c in cameras])
    image_up = np.array([c.camera_to_world[:3, 1] / np.linalg.norm(c.camera_to_world[:3, 1]) for c in cameras])
    _, spread, vt = np.linalg.svd(centres - centres.mean(0))
    if len(cameras) >= 3 and spread[1] > PLANAR_SPREAD * spread[0]:
        normal, how = vt[2], "camera orbit plane"
        side = float(np.mean(image_up @ normal))
        if abs(side) >= CLEAR_UP:
            how += ", sign from image up vectors"
        else:
            side = float(np.mean((centres - pivot) @ normal))
            how += ", sign from cameras above the object"
        return normal * (1.0 if side >= 0 else -1.0), how
    line = vt[0]
    up = image_up.mean(0)
    up = up - (up @ line) * line
    return up / np.linalg.norm(up), "image up vectors (camera centres lie on a line)"


def diameter(points: np.ndarray) -> float:
    """The largest distance between two of the points."""
    try:
        points = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):  # flat or too few: use them all
        points = points[:: max(1, len(points) // 2000)]
    return float(np.sqrt(((points[:, None] - points[None]) ** 2).sum(-1)).max())


def _rotation_to_z(up: np.ndarray) -> np.ndarray:
    """The rotation taking unit ``up`` to +Z (Rodrigues; a half turn about X if up = -Z)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = np.linalg.norm(axis), float(up @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def scene_frame(cameras: list[Camera], masks: Iterable[np.ndarray], points: np.ndarray | None = None,
                where: Path | None = None) -> SceneFrame:
    """The similarity from the cameras' (SfM) world to the scene frame; ``points`` are the
    sparse SfM points (optional), ``where`` names the masks in errors."""
    inside, body = object_points(cameras, masks, points, where)
    pivot = inside.mean(0)
    up, how = up_axis(cameras, pivot)
    R = _rotation_to_z(up)
    first = R @ (cameras[0].centre - pivot)
    turn = -np.pi / 2 - np.arctan2(first[1], first[0])
    c, s = np.cos(turn), np.sin(turn)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ R
    levelled = (inside - pivot) @ R.T
    lo, hi = levelled.min(0), levelled.max(0)
    scale = 1.0 / max(diameter(levelled), 1e-12)
    matrix = np.eye(4)
    matrix[:3, :3] = scale * R
    matrix[:3, 3] = -scale * (R @ pivot + 0.5 * (lo + hi))
    return SceneFrame(matrix, scale, how, body)
