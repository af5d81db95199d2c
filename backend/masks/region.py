"""The object's 3D region: the sparse SfM points that belong to the object.

The orbit's common focus is the point closest to every optical axis, ``p`` minimising
``sum_i |(I - d_i d_i^T)(p - c_i)|^2`` (camera centres ``c_i``, axes ``d_i``): the normal
equations ``sum_i (I - d_i d_i^T) p = sum_i (I - d_i d_i^T) c_i``. Their smallest eigenvalue
over the number of views is the spread of the axes' directions (0 when they are parallel: a
pan or a walk past a wall has no focus). The orbit frame has its origin at the focus, Z along
the normal of the camera centres' plane (signed by the images' up), and the orbit radius
(mean distance of the cameras from the focus) as unit.

Points nearer the focus than ``radius * sin(half field of view)`` (an object that fits in the
frames) are candidates; a dominant plane through the points around the focus (RANSAC, normal
within 35 degrees of up, below the focus) is the ground, and its points are not the object's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .cameras import View

MIN_AXIS_SPREAD = 0.02  # smallest eigenvalue / views: axes within about 8 degrees of each other have no focus
MAX_AXIS_MISS = 0.35  # RMS distance of the axes from the focus, over the orbit radius
MIN_OBJECT_POINTS = 12
NO_OBJECT_FIX = ("give object masks with --masks (one image per frame), or the object's region with "
                 "--object-box X0,Y0,Z0,X1,Y1,Z1 (orbit frame: origin at the point the cameras circle, Z up, "
                 "units of the orbit radius)")


@dataclass
class OrbitFrame:
    origin: np.ndarray  # (3,) SfM world
    axes: np.ndarray  # (3, 3) rows: x, y, z in the SfM world
    radius: float  # SfM units per orbit-frame unit

    def to_local(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, np.float64) - self.origin) @ self.axes.T / self.radius

    def to_world(self, local: np.ndarray) -> np.ndarray:
        return self.origin + self.radius * np.asarray(local, np.float64) @ self.axes


@dataclass
class Region:
    frame: OrbitFrame
    inside: np.ndarray  # (N,) bool: the object's points
    background: np.ndarray  # (N,) bool: points surely not on the object (ground, far away)
    ground: np.ndarray | None  # plane (n, d) with n.x + d = 0 in the SfM world, n up; or None
    focus_found: bool

    def summary(self) -> dict:
        return {"object_points": int(self.inside.sum()), "background_points": int(self.background.sum()),
                "ground_plane": self.ground is not None, "focus": bool(self.focus_found),
                "orbit_radius": float(self.frame.radius)}


def common_focus(views: list[View]) -> tuple[np.ndarray, float, float]:
    """(focus, axis spread, RMS axis miss over the mean camera distance): see the module docstring."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for v in views:
        P = np.eye(3) - np.outer(v.axis, v.axis)
        A += P
        b += P @ v.centre
    spread = float(np.linalg.eigvalsh(A)[0]) / len(views)
    focus = np.linalg.lstsq(A, b, rcond=None)[0]
    miss = [np.linalg.norm((np.eye(3) - np.outer(v.axis, v.axis)) @ (focus - v.centre)) for v in views]
    distance = np.mean([np.linalg.norm(focus - v.centre) for v in views])
    return focus, spread, float(np.sqrt(np.mean(np.square(miss))) / max(distance, 1e-12))


def orbit_frame(views: list[View], origin: np.ndarray) -> OrbitFrame:
    centres = np.array([v.centre for v in views])
    up = np.mean([v.up for v in views], 0)
    z = up / max(np.linalg.norm(up), 1e-12)
    if len(views) >= 3:
        s = np.linalg.svd(centres - centres.mean(0), compute_uv=False)
        if s[1] > 0.2 * s[0]:  # the centres span a plane: its normal is up
            normal = np.linalg.svd(centres - centres.mean(0))[2][2]
            z = normal if normal @ up >= 0 else -normal
    x = np.cross(views[0].axis, z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0, 0], z) if abs(z[0]) < 0.9 else np.cross([0, 1.0, 0], z)
    x /= np.linalg.norm(x)
    radius = float(np.mean([np.linalg.norm(v.centre - origin) for v in views]))
    return OrbitFrame(np.asarray(origin, np.float64), np.array([x, np.cross(z, x), z]), radius)


def ground_plane(points: np.ndarray, up: np.ndarray, below: np.ndarray, threshold: float,
                 iterations: int = 500, seed: int = 0) -> tuple[np.ndarray | None, np.ndarray]:
    """The plane (n, d) holding most ``points`` within ``threshold`` (RANSAC), with its normal
    within 35 degrees of ``up`` and the point ``below`` above it; and its inliers. None when
    the best plane holds fewer than a quarter of the points."""
    n_pts = len(points)
    best, best_in = None, np.zeros(n_pts, bool)
    if n_pts < 30:
        return None, best_in
    rng = np.random.default_rng(seed)
    for _ in range(iterations):
        a, b, c = points[rng.choice(n_pts, 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        if n @ up < 0:
            n = -n
        if n @ up < np.cos(np.radians(35)):
            continue
        d = -n @ a
        if n @ below + d <= threshold:
            continue
        inl = np.abs(points @ n + d) < threshold
        if inl.sum() > best_in.sum():
            best, best_in = (n, d), inl
    if best is None or best_in.sum() < 0.25 * n_pts:
        return None, np.zeros(n_pts, bool)
    n, d = best  # refit to the inliers
    q = points[best_in]
    centre = q.mean(0)
    n2 = np.linalg.svd(q - centre)[2][2]
    n2 = n2 if n2 @ n >= 0 else -n2
    return np.r_[n2, -n2 @ centre], np.abs(points @ n2 - n2 @ centre) < threshold


def object_region(views: list[View], points: np.ndarray, box=None, where=None) -> Region:
    """The object's points among ``points`` (SfM world): inside ``box`` (orbit frame
    ``(x0, y0, z0, x1, y1, z1)``) when given, else near the common focus and off the ground.
    Raises InputError (naming ``where``) when there is no focus to circle or too few points."""
    focus, spread, miss = common_focus(views)
    found = spread >= MIN_AXIS_SPREAD and miss <= MAX_AXIS_MISS
    in_front = np.mean([(v.pose[2, :3] @ focus + v.pose[2, 3]) > 0 for v in views]) if found else 0.0
    found = found and in_front >= 0.9
    if not found and box is None:
        raise InputError(where, "no object can be isolated: the cameras do not circle a common point "
                         f"(axis spread {spread:.3f}, miss {miss:.2f} of the distance)", NO_OBJECT_FIX)
    origin = focus if found else np.array([v.centre for v in views]).mean(0)
    frame = orbit_frame(views, origin)
    points = np.asarray(points, np.float64).reshape(-1, 3)
    local = frame.to_local(points)
    reach = float(np.sin(min(v.half_fov for v in views)))
    dist = np.linalg.norm(local, axis=1)
    plane = None
    if box is not None:
        lo, hi = np.asarray(box[:3], float), np.asarray(box[3:], float)
        inside = np.all((local >= lo) & (local <= hi), axis=1)
        background = ~np.all((local >= lo - 0.1 * (hi - lo)) & (local <= hi + 0.1 * (hi - lo)), axis=1)
    else:
        near = dist < 3 * reach
        threshold = 0.006  # of the orbit radius: SfM points on a textured ground lie this close to its plane
        plane, on_plane = ground_plane(local[near], np.array([0, 0, 1.0]), np.zeros(3), threshold)
        ground = np.zeros(len(points), bool)
        height = np.full(len(points), np.inf)
        if plane is not None:
            ground[np.flatnonzero(near)[on_plane]] = True
            height = local @ plane[:3] + plane[3]
        inside = (dist < reach) & (height > 2 * threshold)
        inside &= _not_stray(local, inside)
        background = (dist > 1.5 * reach) | ground
        if plane is not None:  # back to the SfM world
            n = frame.axes.T @ plane[:3]
            plane = np.r_[n, plane[3] * frame.radius - n @ frame.origin]
    if int(inside.sum()) < MIN_OBJECT_POINTS:
        raise InputError(where, f"no object can be isolated: {int(inside.sum())} SfM points in the object's "
                         f"region (at least {MIN_OBJECT_POINTS} needed)", NO_OBJECT_FIX)
    return Region(frame, inside, background & ~inside, plane, found)


def _not_stray(local: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Drop points far from the rest of the region (beyond 3x the median distance from its
    median point): isolated mismatches that would widen every frame's seed."""
    keep = np.ones(len(local), bool)
    if inside.sum() < MIN_OBJECT_POINTS:
        return keep
    q = local[inside]
    d = np.linalg.norm(q - np.median(q, 0), axis=1)
    keep[np.flatnonzero(inside)[d > 3 * max(np.median(d), 1e-9)]] = False
    return keep
