"""The visual hull as a sampled field: how far inside every object mask a point projects.

The field at a point is the smallest (bilinearly interpolated) mask value over the views
that see the point, so its 0.5 level set is the visual hull with sub-pixel silhouettes.
``miss_views`` > 0 makes it tolerant of bad masks: the (miss_views + 1)-th smallest value
is taken instead. Points that fewer than ``min_views`` views see are outside."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ...capture.images import read_mask
from ...capture.model import Camera, Capture
from ...errors import InputError

LEVEL = 0.5


@dataclass
class HullConfig:
    grid: int = 128  # cells along the longest side of the hull's bounding box
    miss_views: int = 0  # views allowed to disagree with a point being inside (soft tolerance)
    min_view_share: float = 0.5  # share of views whose frame must contain a point
    coarse_grid: int = 48  # first pass, to find the bounding box


@dataclass
class MaskView:
    camera: Camera
    mask: np.ndarray  # (H, W) float32 in [0, 1]


def mask_views(capture: Capture) -> list[MaskView]:
    if not capture.has_masks:
        raise InputError(capture.root, "space carving needs an object mask for every frame",
                         "add masks, or choose --init sphere, box, points or a mesh file")
    return [MaskView(f.camera, read_mask(f.mask)) for f in capture.frames]


def _bilinear(mask: np.ndarray, uv: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    x = np.clip(uv[:, 0] - 0.5, 0, w - 1)
    y = np.clip(uv[:, 1] - 0.5, 0, h - 1)
    x0, y0 = np.minimum(x.astype(np.int64), w - 2 if w > 1 else 0), np.minimum(y.astype(np.int64), h - 2 if h > 1 else 0)
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    return ((1 - fy) * ((1 - fx) * mask[y0, x0] + fx * mask[y0, x1])
            + fy * ((1 - fx) * mask[y1, x0] + fx * mask[y1, x1]))


def sample(views: list[MaskView], points: np.ndarray, config: HullConfig, chunk: int = 1 << 19) -> np.ndarray:
    """The hull field at ``points`` (N, 3)."""
    out = np.empty(len(points), np.float32)
    k = config.miss_views + 1
    for s in range(0, len(points), chunk):
        p = points[s:s + chunk]
        smallest = np.ones((k, len(p)), np.float32)  # the k smallest values seen so far
        seen = np.zeros(len(p), np.int32)
        for view in views:
            # with k = 1 a point at 0 stays at 0 whatever the other views see: the rest skip it
            live = np.flatnonzero(smallest[0] > 0) if k == 1 else None
            if live is not None and len(live) == len(p):
                live = None
            q = p if live is None else p[live]
            if len(q) == 0:
                break
            uv, depth = view.camera.project(q)
            h, w = view.mask.shape
            visible = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= w) & (uv[:, 1] >= 0) & (uv[:, 1] <= h)
            value = np.where(visible, _bilinear(view.mask, uv), 1.0).astype(np.float32)
            if k == 1 and live is not None:
                seen[live] += visible
                smallest[0, live] = np.minimum(smallest[0, live], value)
            elif k == 1:
                seen += visible
                np.minimum(smallest[0], value, out=smallest[0])
            else:
                seen += visible
                smallest = np.sort(np.vstack([smallest, value[None]]), axis=0)[:k]
        out[s:s + chunk] = np.where(seen >= max(2, config.min_view_share * len(views)), smallest[-1], 0.0)
    return out


def grid_points(lo: np.ndarray, hi: np.ndarray, cells: int) -> tuple[np.ndarray, tuple[int, int, int], float]:
    """Grid over the box [lo, hi] with ``cells`` cells along its longest side."""
    spacing = float((hi - lo).max()) / cells
    shape = tuple(int(np.ceil((hi[i] - lo[i]) / spacing)) + 1 for i in range(3))
    axes = [lo[i] + spacing * np.arange(shape[i]) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return pts, shape, spacing


@dataclass
class HullField:
    values: np.ndarray  # (nx, ny, nz)
    origin: np.ndarray
    spacing: float

    def points(self) -> np.ndarray:
        idx = np.stack(np.meshgrid(*[np.arange(n) for n in self.values.shape], indexing="ij"), -1)
        return self.origin + self.spacing * idx.reshape(-1, 3)

    @property
    def inside(self) -> np.ndarray:
        return self.values > LEVEL

    def largest_part(self) -> np.ndarray:
        """The largest connected (6-neighbour) part of the inside voxels, as a boolean grid."""
        labels, n = ndimage.label(self.inside)
        if n <= 1:
            return labels > 0
        return labels == 1 + np.argmax(np.bincount(labels.ravel())[1:])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        idx = np.argwhere(self.largest_part())
        return self.origin + self.spacing * idx.min(0), self.origin + self.spacing * idx.max(0)


def field_on_box(views: list[MaskView], lo: np.ndarray, hi: np.ndarray, cells: int,
                 config: HullConfig) -> HullField:
    pts, shape, spacing = grid_points(lo, hi, cells)
    return HullField(sample(views, pts, config).reshape(shape), lo.copy(), spacing)


def hull_box(capture: Capture, views: list[MaskView], config: HullConfig) -> tuple[np.ndarray, np.ndarray]:
    """The bounding box of the visual hull, from a coarse pass around the cameras' focus."""
    centre, radius = capture.bounds_hint()
    half = 1.5 * radius
    for _ in range(4):
        lo, hi = centre - half, centre + half
        coarse = field_on_box(views, lo, hi, config.coarse_grid, config)
        if not coarse.inside.any():
            raise InputError(capture.root, "the object masks share no common volume in front of the cameras",
                             "check that masks are white on the object and that the camera poses are right")
        inside = coarse.largest_part()
        touches = inside[[0, -1]].any() or inside[:, [0, -1]].any() or inside[:, :, [0, -1]].any()
        if not touches:
            a, b = coarse.bounds()
            pad = 2 * coarse.spacing
            return a - pad, b + pad
        half *= 2  # the hull reaches the box: widen it
    raise InputError(capture.root, "the visual hull is unbounded (the masks do not enclose the object)",
                     "give masks with background around the object, or choose --init sphere")


def visual_hull(capture: Capture, config: HullConfig | None = None,
                views: list[MaskView] | None = None) -> HullField:
    """The hull field on a grid padded so its outer layer lies outside the hull."""
    config = config or HullConfig()
    views = views if views is not None else mask_views(capture)
    lo, hi = hull_box(capture, views, config)
    pad = 2 * float((hi - lo).max()) / config.grid
    return field_on_box(views, lo - pad, hi + pad, config.grid + 4, config)
