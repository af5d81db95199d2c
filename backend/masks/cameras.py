"""The SfM cameras as the mask pipeline uses them: projection into the (distorted) frames."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..capture.undistort import distort


@dataclass
class View:
    """One registered frame's camera: world-to-camera ``pose`` [R|t] (OpenCV axes), intrinsics
    in frame pixels (corner origin), the shared distortion (OpenCV names)."""

    name: str
    pose: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: dict

    @property
    def centre(self) -> np.ndarray:
        return -self.pose[:, :3].T @ self.pose[:, 3]

    @property
    def axis(self) -> np.ndarray:
        """The optical axis (unit, world)."""
        return self.pose[2, :3] / np.linalg.norm(self.pose[2, :3])

    @property
    def up(self) -> np.ndarray:
        """The image's up direction in the world (OpenCV's -Y)."""
        return -self.pose[1, :3]

    @property
    def half_fov(self) -> float:
        """Half the angle the shorter image side spans (radians)."""
        return float(np.arctan(0.5 * min(self.width / self.fx, self.height / self.fy)))

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) and depths (N,) of world ``points`` (N, 3)."""
        cam = np.asarray(points, np.float64) @ self.pose[:, :3].T + self.pose[:, 3]
        depth = cam[:, 2]
        xy = cam[:, :2] / np.where(np.abs(depth) > 1e-12, depth, 1e-12)[:, None]
        if any(self.distortion.values()):
            xy = distort(xy, self.distortion)
        return np.c_[self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy], depth


def views_of(sfm) -> list[View]:
    """The registered frames of an SfM result (``backend.video.sfm.SfmResult``), in capture order."""
    return [View(n, np.asarray(sfm.poses[n], np.float64), sfm.fx, sfm.fy, sfm.cx, sfm.cy, sfm.width, sfm.height,
                 dict(sfm.distortion)) for n in sfm.names if n in sfm.poses]
