"""Camera refinement by silhouette coherence: the SfM's poses, points, focal length and k1
adjusted once more, against the feature observations and the masks' epipolar tangencies.

Two views of an object see it inside two silhouette cones. The planes through their baseline
that touch the object touch both cones, so the outermost epipolar planes of one view's
silhouette are those of the other's (epipolar tangency, as in silhouette-based calibration of
turntable sequences). Each pair of views gives two residuals: the differences of the extreme
angles, about the baseline, of the planes through its silhouettes' convex hulls (a plane
through an outside epipole touches a silhouette at its hull), times the focal length (pixels).

Why: feature tracks on a sparse ring are short, and bundle adjustment of them alone leaves a
flat valley in which poses drift at an unchanged reprojection error; the silhouettes pin the
poses where the features do not (``bench sfm`` compares both with calibrated cameras).

Where a mask is cut by the frame border, an extreme on the border is the frame's: that
residual is left out. Pairs where either view sees the other's camera near or inside the
silhouette (the planes' angles then spread over more than ``max_spread_deg``) take no part.
The result is kept only when it lowers the tangency residuals without raising the
reprojection error much; a frame whose mask fits no other is dropped first (``refine``)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial import ConvexHull, QhullError
from scipy.spatial.transform import Rotation

from ..capture.undistort import distort, undistort_points


@dataclass
class SilhouetteOptions:
    weight: float = 1.0  # tangency residuals (pixels) against reprojection residuals (pixels)
    robust_px: float = 1.0  # soft-L1 scale of both kinds of residual
    # pairs whose silhouettes' planes spread wider are left out (the other camera is seen near
    # or inside the silhouette)
    max_spread_deg: float = 120.0
    # pairs: frames this many evenly spaced steps apart in capture order (all pairs up to
    # max_partners + 1 frames), so that the residuals grow with the frames, not their square
    max_partners: int = 16
    max_evaluations: int = 60
    min_frames: int = 3  # fewer usable masks: no refinement
    outlier_px: float = 5.0  # a frame's median tangency residual above this (and 10x all's) drops it
    # the result's RMS reprojection error may grow to slack x before + floor at most
    reprojection_slack: float = 1.25
    reprojection_floor_px: float = 0.05


def hull_points(mask: np.ndarray) -> np.ndarray | None:
    """Corners of the convex hull of the mask's pixels (x, y, corner-origin pixels), or None
    when the mask is empty or degenerate."""
    inside = np.asarray(mask) > 0.5
    if not inside.any():
        return None
    y, x = np.nonzero(inside)
    corners = np.concatenate([np.c_[x + dx, y + dy] for dx in (0, 1) for dy in (0, 1)]).astype(np.float64)
    try:
        return corners[ConvexHull(corners).vertices]
    except QhullError:
        return None


class _Problem:
    """Parameters: per frame a rotation vector (applied before the SfM rotation) and a
    translation, then a focal-length scale and k1, then the points."""

    def __init__(self, result, hulls: dict[str, np.ndarray], options: SilhouetteOptions):
        """``hulls``: registered frame name -> silhouette hull, in capture order."""
        self.options = options
        self.names = [n for n in result.names if n in result.poses]
        index = {n: k for k, n in enumerate(self.names)}
        frame_of = {k: index.get(n) for k, n in enumerate(result.names)}
        obs = result.observations
        keep = np.array([frame_of[int(f)] is not None for f in obs[:, 1]], bool)
        self.pid = obs[keep, 0].astype(int)
        self.fid = np.array([frame_of[int(f)] for f in obs[keep, 1]], int)
        self.uv = obs[keep, 2:]
        self.R0 = np.array([result.poses[n][:, :3] for n in self.names])
        t0 = np.array([result.poses[n][:, 3] for n in self.names])
        self.f0 = np.array([result.fx, result.fy])
        self.c = np.array([result.cx, result.cy])
        self.dist = dict(result.distortion)
        self.n = len(self.names)
        self.x0 = np.concatenate([np.zeros(3 * self.n), t0.ravel(), [1.0, self.dist.get("k1", 0.0)],
                                  result.points.ravel()])
        self.centre = np.median(result.points, axis=0) if len(result.points) else np.zeros(3)
        self.frames = np.array([index[n] for n in hulls], int)
        size = max(len(h) for h in hulls.values())  # hulls padded by repeating a point (same extremes)
        self.hulls = np.array([np.concatenate([h, np.repeat(h[:1], size - len(h), 0)]) for h in hulls.values()])
        on_border = ((self.hulls <= 0) | (self.hulls >= [result.width, result.height])).any(axis=2)
        self.pairs = np.zeros((0, 2), int)
        self.valid = np.zeros((0, 2))
        if len(self.frames) >= 2:
            a, b = np.triu_indices(len(self.frames), 1)
            offsets = np.unique(np.round(np.linspace(1, len(self.frames) - 1, options.max_partners)))
            self.pairs = np.c_[a, b][np.isin(b - a, offsets)]
            angles, spread = self._plane_angles(self.x0)
            keep = spread < np.radians(options.max_spread_deg)
            self.pairs = self.pairs[keep]
            # an extreme on the frame border is the frame's, not the object's: that residual
            # is left out (one inside the frame is the whole silhouette's extreme)
            valid = np.ones((len(self.pairs), 2), bool)
            for view, angle in zip(self.pairs.T, angles):
                cut = on_border[view]
                angle = angle[keep]
                for e, index in enumerate((angle.argmin(axis=1), angle.argmax(axis=1))):
                    valid[:, e] &= ~cut[np.arange(len(index)), index]
            self.valid = valid.astype(np.float64)

    def unpack(self, x):
        n = self.n
        R = Rotation.from_rotvec(x[:3 * n].reshape(n, 3)).as_matrix() @ self.R0
        t = x[3 * n:6 * n].reshape(n, 3)
        scale, k1 = x[6 * n:6 * n + 2]
        return R, t, self.f0 * scale, k1, x[6 * n + 2:].reshape(-1, 3)

    def _plane_angles(self, x):
        """The angles about each pair's baseline of the planes through each view's hull points,
        (p, L) for each view, and their largest spread."""
        R, t, f, k1, _ = self.unpack(x)
        R, t = R[self.frames], t[self.frames]
        C = -np.einsum("kji,kj->ki", R, t)
        xn = undistort_points((self.hulls - self.c) / f, dict(self.dist, k1=k1), iterations=10)
        rays = np.einsum("kli,kij->klj", np.concatenate([xn, np.ones(xn.shape[:2] + (1,))], axis=2), R)
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        base = C[j] - C[i]
        base /= np.linalg.norm(base, axis=1, keepdims=True)
        ref = self.centre - C[i]
        ref -= base * np.sum(ref * base, axis=1, keepdims=True)
        ref /= np.linalg.norm(ref, axis=1, keepdims=True)
        other = np.cross(base, ref)
        angles = [np.arctan2(np.einsum("pld,pd->pl", rays[view], other), np.einsum("pld,pd->pl", rays[view], ref))
                  for view in (i, j)]
        return angles, np.maximum(*(np.ptp(a, axis=1) for a in angles))

    def reprojection(self, x) -> np.ndarray:
        R, t, f, k1, P = self.unpack(x)
        cam = np.einsum("nij,nj->ni", R[self.fid], P[self.pid]) + t[self.fid]
        return (distort(cam[:, :2] / cam[:, 2:3], dict(self.dist, k1=k1)) * f + self.c - self.uv).ravel()

    def tangency(self, x) -> np.ndarray:
        """Per pair, the differences of the two views' smallest and largest plane angles (pixels)."""
        (a, b), _ = self._plane_angles(x)
        gap = np.c_[a.min(1) - b.min(1), a.max(1) - b.max(1)]
        return (gap * self.valid * self.f0.mean() * x[6 * self.n]).ravel()

    def frame_medians(self, x) -> dict[str, float]:
        """Each frame's median absolute tangency residual over its pairs."""
        per_pair = np.abs(self.tangency(x)).reshape(-1, 2).max(axis=1)
        frames = self.frames[self.pairs]
        return {self.names[k]: float(np.median(per_pair[(frames == k).any(axis=1)]))
                for k in self.frames if (frames == k).any()}

    def residuals(self, x) -> np.ndarray:
        return np.concatenate([self.reprojection(x), self.options.weight * self.tangency(x)])

    def sparsity(self) -> sparse.csr_matrix:
        n, m = self.n, len(self.fid)
        rows, cols = [], []
        for axis in range(2):
            r = 2 * np.arange(m) + axis
            for q in range(3):
                rows += [r, r, r]
                cols += [3 * self.fid + q, 3 * n + 3 * self.fid + q, 6 * n + 2 + 3 * self.pid + q]
            for q in range(2):
                rows.append(r)
                cols.append(np.full(m, 6 * n + q))
        frames = self.frames[self.pairs]  # (p, 2) problem frame indices
        for k in range(2 * len(self.pairs)):
            r = np.full(14, 2 * m + k)
            i, j = frames[k // 2]
            rows.append(r)
            cols.append(np.r_[[3 * i + q for q in range(3)], [3 * j + q for q in range(3)],
                              [3 * n + 3 * i + q for q in range(3)], [3 * n + 3 * j + q for q in range(3)],
                              6 * n, 6 * n + 1])
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        shape = (2 * m + 2 * len(self.pairs), len(self.x0))
        return sparse.csr_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=shape)


def refine(result, masks: dict[str, np.ndarray], options: SilhouetteOptions | None = None):
    """``result`` (an SfmResult) adjusted with the tangencies of ``masks`` (frame name ->
    mask in frame pixels), and a summary for the report. The summary's ``applied`` says
    whether the adjusted cameras were kept (else ``result`` comes back unchanged).

    A frame whose tangencies stay far off after the adjustment (its median over its pairs
    above ``outlier_px`` and ten times the median of all) has a mask that does not fit the
    others: it is dropped (``dropped``) and the adjustment starts again without it."""
    options = options or SilhouetteOptions()
    start = time.perf_counter()
    hulls = {}
    for name in result.names:
        if name in masks and name in result.poses:
            hull = hull_points(masks[name])
            if hull is not None:
                hulls[name] = hull
    summary = {"frames": len(hulls), "pairs": 0, "applied": False, "dropped": []}
    if not len(result.observations):
        summary["reason"] = "no feature observations"
        return result, summary
    while True:
        if len(hulls) < options.min_frames:
            summary["reason"] = f"{len(hulls)} frames with silhouettes (at least {options.min_frames} needed)"
            return result, summary
        problem = _Problem(result, hulls, options)
        summary.update(frames=len(hulls), pairs=len(problem.pairs), residuals=int(problem.valid.sum()))
        if not problem.valid.any():
            summary["reason"] = "no pair of views sees the object whole from outside the other's silhouette"
            return result, summary
        if not np.all(np.isfinite(problem.residuals(problem.x0))):
            summary["reason"] = "a point projects to infinity"
            return result, summary
        fit = least_squares(problem.residuals, problem.x0, jac_sparsity=problem.sparsity(), loss="soft_l1",
                            f_scale=options.robust_px, x_scale="jac", method="trf", tr_solver="lsmr",
                            max_nfev=options.max_evaluations)
        off = problem.frame_medians(fit.x)
        limit = max(options.outlier_px, 10 * float(np.median(np.abs(problem.tangency(fit.x)))))
        worst = max(off, key=off.get)
        if off[worst] <= limit:
            break
        summary["dropped"].append(worst)
        del hulls[worst]

    def rms(x):
        return float(np.sqrt(np.mean(problem.reprojection(x) ** 2)))

    def tangency(x):
        return np.abs(problem.tangency(x))

    before, after = (rms(problem.x0), tangency(problem.x0)), (rms(fit.x), tangency(fit.x))
    summary.update(reprojection_rms_px=[round(before[0], 4), round(after[0], 4)],
                   tangency_median_px=[round(float(np.median(t)), 4) for t in (before[1], after[1])],
                   tangency_max_px=[round(float(t.max()), 4) for t in (before[1], after[1])],
                   seconds=round(time.perf_counter() - start, 2))
    better = np.sum(after[1] ** 2) < np.sum(before[1] ** 2)
    within = after[0] <= options.reprojection_slack * before[0] + options.reprojection_floor_px
    if not (np.all(np.isfinite(fit.x)) and better and within):
        summary["reason"] = "the adjustment did not improve the tangencies within the reprojection error"
        return result, summary
    R, t, f, k1, points = problem.unpack(fit.x)
    poses = {n: np.c_[R[k], t[k]] for k, n in enumerate(problem.names)}
    error = float(np.mean(np.linalg.norm(problem.reprojection(fit.x).reshape(-1, 2), axis=1)))
    summary["applied"] = True
    return dataclasses.replace(result, poses=poses, fx=float(f[0]), fy=float(f[1]), points=points,
                               distortion=dict(result.distortion, k1=float(k1)), reprojection_error_px=error), summary
