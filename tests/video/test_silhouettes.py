"""Camera refinement by silhouette coherence (``backend.video.silhouettes``) on a synthetic
ring around an ellipsoid, whose silhouettes are exact up to the pixel grid."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from backend.metrics.geometry import align_similarity
from backend.video.sfm import SfmResult
from backend.video.silhouettes import hull_points, refine

SIZE, FOCAL, DISTANCE = 200, 400.0, 4.0
AXES = np.array([1.0, 0.6, 0.4])
ORIENT = Rotation.from_euler("xyz", [20, -30, 40], degrees=True).as_matrix()
QUADRIC = ORIENT @ np.diag(1 / AXES ** 2) @ ORIENT.T  # x^T Q x = 1 on the surface


def ring(count: int) -> list[np.ndarray]:
    """World-to-camera [R|t] (OpenCV axes) on a ring at varying heights, looking at the origin."""
    poses = []
    for k in range(count):
        a = 2 * np.pi * k / count
        centre = DISTANCE * np.array([np.cos(a), np.sin(a), 0.3 * np.sin(3 * a)])
        forward = -centre / np.linalg.norm(centre)
        right = np.cross(forward, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.array([right, down, forward])
        poses.append(np.c_[R, -R @ centre])
    return poses


def silhouette(pose: np.ndarray) -> np.ndarray:
    R, t = pose[:, :3], pose[:, 3]
    centre = -R.T @ t
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    rays = np.stack([(x - SIZE / 2) / FOCAL, (y - SIZE / 2) / FOCAL, np.ones_like(x)], -1) @ R
    a = np.einsum("hwi,ij,hwj->hw", rays, QUADRIC, rays)
    b = rays @ (QUADRIC @ centre)
    c = centre @ QUADRIC @ centre - 1
    return (b * b - a * c >= 0).astype(np.float32)


def synthetic(count: int) -> tuple[SfmResult, dict]:
    """Exact cameras in two halves of the ring that share no feature track (a weak link on each
    side), points on the surface observed by the half that faces them, and the silhouettes.
    Moving one half and its points by a similarity leaves every reprojection error as it was."""
    poses = ring(count)
    rng = np.random.default_rng(3)
    unit = rng.normal(size=(600, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    points = (unit * AXES) @ ORIENT.T
    normals = points @ QUADRIC
    centres = np.array([-p[:, :3].T @ p[:, 3] for p in poses])
    facing = np.einsum("pd,kpd->kp", normals, centres[:, None] - points[None]) > 0  # (camera, point)
    half = np.arange(count) >= count // 2
    side = facing[half].sum(0) > facing[~half].sum(0)  # the half that sees each point more
    observations = []
    for k, pose in enumerate(poses):
        cam = points @ pose[:, :3].T + pose[:, 3]
        uv = FOCAL * cam[:, :2] / cam[:, 2:3] + SIZE / 2
        observations += [(p, k, *uv[p]) for p in np.flatnonzero(facing[k] & (side == half[k]))]
    names = [f"{k:02d}" for k in range(count)]
    result = SfmResult(names=names, poses=dict(zip(names, poses)), width=SIZE, height=SIZE, fx=FOCAL, fy=FOCAL,
                       cx=SIZE / 2, cy=SIZE / 2, distortion={"k1": 0.0}, points=points, reprojection_error_px=0.0,
                       method="incremental", observations=np.array(observations))
    return result, {n: silhouette(p) for n, p in zip(names, poses)}, side


def centre_errors(poses: dict, truth: SfmResult) -> np.ndarray:
    """Camera centre errors after a similarity fitted to the centres, as a share of the ring."""
    def centres(ps):
        return np.array([-ps[n][:, :3].T @ ps[n][:, 3] for n in truth.names])

    ours, theirs = centres(poses), centres(truth.poses)
    m = align_similarity(ours, theirs)
    return np.linalg.norm(ours @ m[:3, :3].T + m[:3, 3] - theirs, axis=1) / DISTANCE


def test_hull_points_are_the_covered_pixels_corners():
    mask = np.zeros((10, 12), np.float32)
    assert hull_points(mask) is None
    mask[2:5, 3:7] = 1
    assert sorted(map(tuple, hull_points(mask))) == [(3, 2), (3, 5), (7, 2), (7, 5)]


def moved_half(truth: SfmResult, side: np.ndarray) -> SfmResult:
    """Frames 6-11 and the points they observe moved by a similarity (2 degrees, 5 % scale,
    a shift): every reprojection error stays as it was."""
    turn = Rotation.from_rotvec(np.radians(2.0) * np.array([0.3, 0.4, 0.866])).as_matrix()
    scale, shift = 1.05, np.array([0.1, -0.05, 0.08])
    moved = {n: p.copy() for n, p in truth.poses.items()}
    for n in truth.names[6:]:
        R, t = moved[n][:, :3], moved[n][:, 3]  # x -> scale turn x + shift applied to the world
        R2 = R @ turn.T
        moved[n] = np.c_[R2, scale * t - R2 @ shift]
    points = truth.points.copy()
    points[side] = scale * points[side] @ turn.T + shift
    return SfmResult(**{**truth.__dict__, "poses": moved, "points": points})


def test_silhouettes_join_two_halves_that_share_no_track():
    """One half of the ring and its points moved by a similarity: the features cannot tell,
    the silhouettes' tangencies bring it back."""
    truth, masks, side = synthetic(12)
    start = moved_half(truth, side)
    assert np.sqrt(np.mean(_reprojection(start) ** 2)) < 1e-6  # the move is invisible to the features

    out, summary = refine(start, masks)
    assert summary["applied"] and summary["frames"] == 12 and summary["pairs"] > 30
    before, after = summary["tangency_max_px"]
    assert after < 2.0 and before > 5 * after
    error_before, error_after = centre_errors(start.poses, truth), centre_errors(out.poses, truth)
    print(f"centre error max {error_before.max():.2%} -> {error_after.max():.2%}")
    assert error_before.max() > 0.02 and error_after.max() < 0.005
    # a narrow lens trades focal length against distance and k1: both stay close
    assert abs(out.fx - FOCAL) < 0.02 * FOCAL and abs(out.distortion["k1"]) < 0.1


def _reprojection(result: SfmResult) -> np.ndarray:
    obs = result.observations
    out = []
    for p, k, u, v in obs:
        pose = result.poses[result.names[int(k)]]
        cam = pose[:, :3] @ result.points[int(p)] + pose[:, 3]
        out.append(FOCAL * cam[:2] / cam[2] + SIZE / 2 - [u, v])
    return np.array(out)


def test_a_mask_that_fits_no_other_is_dropped():
    """Frame 3's mask shifted by 20 px (a mask from another frame, say): its tangencies stay
    far off, so it is dropped and the adjustment without it keeps every camera in place."""
    truth, masks, _ = synthetic(12)
    masks = dict(masks, **{"03": np.roll(masks["03"], 20, axis=1)})
    out, summary = refine(truth, masks)
    assert summary["dropped"] == ["03"] and summary["frames"] == 11 and summary["applied"]
    assert centre_errors(out.poses, truth).max() < 0.005


def test_masks_cut_by_the_frame_border_keep_their_whole_extremes():
    """Frames 40 px shorter, so that most silhouettes run off the bottom edge: the extremes
    there are the frame's and are left out, the others still join the two halves."""
    truth, masks, side = synthetic(12)
    rows = SIZE - 40
    truth = SfmResult(**{**truth.__dict__, "height": rows})
    masks = {n: m[:rows] for n, m in masks.items()}
    assert sum(m[-1].any() for m in masks.values()) >= 6
    start = moved_half(truth, side)
    out, summary = refine(start, masks)
    assert summary["applied"] and summary["frames"] == 12 and summary["dropped"] == []
    assert summary["residuals"] < 2 * summary["pairs"]
    before, after = centre_errors(start.poses, truth).max(), centre_errors(out.poses, truth).max()
    print(f"cut masks: centre error max {before:.2%} -> {after:.2%}")
    assert before > 0.02 and after < 0.01  # 0.26 % with the whole silhouettes, 0.63 % cut
