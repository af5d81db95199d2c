"""Cross-frame consistency of masks: their visual hull on a voxel grid, reprojected.

A voxel stays when at most ``tolerance`` of the views that see it (its centre inside the
frame) have it outside their mask, and more have it inside, so one wrong mask does not carve
the object away in all the others (and a voxel only a few views see needs their masks). The hull's projection into a frame (voxel centres splatted with the voxel's projected
size, then closed) against that frame's mask gives the frame's IoU: a mask that disagrees with
what the other views agree on is wrong (or the object moved).

The strict hull (``tolerance`` 0) of the frames that agree with the tolerant one, less the frame
itself, contains the object wherever those masks do, so its projection bounds a frame's mask
from outside: the next segmentation round is seeded by it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cameras import View

# cv2 is imported inside the functions: bpy must be imported before it in one process (tests, scripts)


@dataclass
class Hull:
    centres: np.ndarray  # (M, 3) kept voxels' centres, SfM world
    voxel: float  # voxel side, SfM units

    @property
    def empty(self) -> bool:
        return not len(self.centres)


class Votes:
    """Every view's verdict on the voxels of the box ``lo``..``hi`` (SfM world, ``grid`` voxels
    along its longer side): per view, the voxels inside its mask and those it sees outside."""

    def __init__(self, views: list[View], masks: dict[str, np.ndarray], lo: np.ndarray, hi: np.ndarray,
                 grid: int = 80):
        self.voxel = float(np.max(hi - lo)) / grid
        axes = [np.arange(lo[k] + self.voxel / 2, hi[k], self.voxel) for k in range(3)]
        self.centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        self.inside, self.outside = {}, {}
        for v in views:
            if v.name not in masks:
                continue
            m = masks[v.name] > 0.5
            uv, depth = v.project(self.centres)
            x, y = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
            ok = (depth > 0) & (x >= 0) & (y >= 0) & (x < m.shape[1]) & (y < m.shape[0])
            hit = np.zeros(len(self.centres), bool)
            hit[ok] = m[y[ok], x[ok]]
            self.inside[v.name], self.outside[v.name] = hit, ok & ~hit

    def hull(self, names=None, tolerance: int = 1, exclude: str | None = None) -> Hull:
        """The voxels that at most ``tolerance`` of the views ``names`` (all, less ``exclude``)
        see outside their masks, and more see inside."""
        names = [n for n in (self.inside if names is None else names) if n != exclude and n in self.inside]
        out = np.zeros(len(self.centres), np.int32)
        into = np.zeros(len(self.centres), np.int32)
        for n in names:
            into += self.inside[n]
            out += self.outside[n]
        keep = (out <= tolerance) & (into > out)
        return Hull(self.centres[keep], self.voxel)


def carve(views: list[View], masks: dict[str, np.ndarray], lo: np.ndarray, hi: np.ndarray, grid: int = 80,
          tolerance: int = 1) -> Hull:
    """The voxels of the box ``lo``..``hi`` (SfM world) that the masks agree on (see above)."""
    return Votes(views, masks, lo, hi, grid).hull(tolerance=tolerance)


def project_hull(hull: Hull, view: View) -> np.ndarray:
    """The hull's silhouette in ``view`` (float32 0/1, frame size)."""
    import cv2  # see the note at the top

    img = np.zeros((view.height, view.width), np.uint8)
    if hull.empty:
        return img.astype(np.float32)
    uv, depth = view.project(hull.centres)
    front = depth > 0
    uv, depth = uv[front], depth[front]
    x, y = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
    ok = (x >= 0) & (y >= 0) & (x < view.width) & (y < view.height)
    img[y[ok], x[ok]] = 1
    if not ok.any():
        return img.astype(np.float32)
    r = max(1, int(round(0.5 * hull.voxel * view.fx / float(np.median(depth[ok])))))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    img = cv2.dilate(img, kernel)
    return cv2.morphologyEx(img, cv2.MORPH_CLOSE, kernel).astype(np.float32)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a) > 0.5, np.asarray(b) > 0.5
    union = int((a | b).sum())
    return float((a & b).sum() / union) if union else 1.0
