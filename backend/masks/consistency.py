"""Cross-frame consistency of masks: their visual hull on a voxel grid, reprojected.

A voxel stays when at most ``tolerance`` of the views that see it (its centre inside the
frame) have it outside their mask, and more have it inside, so one wrong mask does not carve
the object away in all the others (and a voxel only a few views see needs their masks). The hull's projection into a frame (voxel centres splatted with the voxel's projected
size, then closed) against that frame's mask gives the frame's IoU: a mask that disagrees with
what the other views agree on is wrong (or the object moved)."""

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


def carve(views: list[View], masks: dict[str, np.ndarray], lo: np.ndarray, hi: np.ndarray, grid: int = 80,
          tolerance: int = 1) -> Hull:
    """The voxels of the box ``lo``..``hi`` (SfM world) that the masks agree on (see above)."""
    size = float(np.max(hi - lo))
    voxel = size / grid
    axes = [np.arange(lo[k] + voxel / 2, hi[k], voxel) for k in range(3)]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    out = np.zeros(len(centres), np.int32)
    into = np.zeros(len(centres), np.int32)
    for v in views:
        if v.name not in masks:
            continue
        m = masks[v.name] > 0.5
        uv, depth = v.project(centres)
        x, y = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
        ok = (depth > 0) & (x >= 0) & (y >= 0) & (x < m.shape[1]) & (y < m.shape[0])
        hit = np.zeros(len(centres), bool)
        hit[ok] = m[y[ok], x[ok]]
        into += hit
        out += ok & ~hit
    keep = (out <= tolerance) & (into > out)
    return Hull(centres[keep], voxel)


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
