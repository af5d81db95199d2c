"""Structure from motion against known poses: the Middlebury dino and the instant-ngp fox.

Each capture's frames go through the same SfM the video path uses (``backend.video.sfm``,
pycolmap on the CPU, frames in file order); the registered cameras are aligned to the given
ones by a similarity fitted to their centres (``metrics.geometry.align_similarity``), then
compared per camera: centre distance as a share of the ring radius (the mean distance of the
given centres from their centroid) and rotation angle. The dino's poses are its calibration;
the fox's are the COLMAP poses its ``transforms.json`` ships with.

Goal: rotation error < 2 degrees and centre error < 2 % of the ring radius."""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from .. import fsio, variant
from ..capture.importers import middlebury, nerf
from ..metrics.geometry import align_similarity
from ..video.sfm import solve
from . import _records
from ._data import SHARED_DATA

SHARED = SHARED_DATA / "captures"
CAPTURES = {"dino": SHARED / "middlebury_dinoSparseRing", "fox": SHARED / "fox_instant_ngp"}
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0])


def add_arguments(parser) -> None:
    parser.add_argument("--captures", default="dino,fox", help="comma-separated: dino, fox (default: %(default)s)")
    parser.add_argument("--out", type=Path, help="write the figures here as JSON")


def compare(poses: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict:
    """Per-camera errors of SfM ``poses`` (3x4 world-to-camera, OpenCV) against ``truth``
    (4x4 camera-to-world, OpenGL axes) after a similarity fitted to the centres."""
    names = [n for n in truth if n in poses]
    ours_c2w = []
    for n in names:
        R, t = poses[n][:, :3], poses[n][:, 3]
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = R.T @ OPENCV_TO_OPENGL, -R.T @ t
        ours_c2w.append(c2w)
    ours = np.array([m[:3, 3] for m in ours_c2w])
    theirs = np.array([truth[n][:3, 3] for n in names])
    m = align_similarity(ours, theirs)
    s = float(np.linalg.norm(m[:3, 0]))
    R, t = m[:3, :3] / s, m[:3, 3]
    radius = np.linalg.norm(theirs - theirs.mean(0), axis=1).mean()
    centre = np.linalg.norm(s * ours @ R.T + t - theirs, axis=1) / radius
    rotation = []
    for m, n in zip(ours_c2w, names):
        rel = (R @ m[:3, :3]).T @ truth[n][:3, :3]
        rotation.append(np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1.0, 1.0))))
    rotation = np.array(rotation)
    return {"compared": len(names), "centre_error_pct": {"max": 100 * centre.max(), "mean": 100 * centre.mean()},
            "rotation_error_deg": {"max": rotation.max(), "mean": rotation.mean()}}


def measure(name: str) -> dict:
    source = CAPTURES[name]
    with tempfile.TemporaryDirectory(prefix=f"sfm-{name}-") as work:
        capture = middlebury.load(source, Path(work)) if name == "dino" else nerf.load(source)
        truth = {f.name: f.camera.camera_to_world for f in capture.frames}
        masks = [Path(f.mask) for f in capture.frames] if all(f.mask for f in capture.frames) else None
        start = time.perf_counter()
        result = solve([Path(f.image) for f in capture.frames], Path(work), source=source, masks=masks)
        seconds = time.perf_counter() - start
    return {"frames": result.total, "registered": result.registered, "method": result.method,
            "reprojection_error_px": result.reprojection_error_px, "seconds": round(seconds, 1),
            "stage_seconds": {k: round(v, 1) for k, v in result.seconds.items()}, "silhouettes": result.silhouettes,
            **compare(result.poses, truth)}


def run(args) -> int:
    variant.choose()
    figures = {}
    print(f"load {os.getloadavg()[0]:.1f}, {os.cpu_count()} cores", flush=True)
    for name in [n for n in args.captures.split(",") if n]:
        f = figures[name] = measure(name)
        c, r = f["centre_error_pct"], f["rotation_error_deg"]
        ok = r["max"] < 2.0 and c["max"] < 2.0
        print(f"{name:<5} {f['registered']}/{f['frames']} registered ({f['method']}, {f['reprojection_error_px']:.2f} px)"
              f" in {f['seconds'] / 60:.1f} min; centre error max {c['max']:.2f} % mean {c['mean']:.2f} % of the ring"
              f" radius; rotation error max {r['max']:.2f} mean {r['mean']:.2f} deg; goal (< 2 deg, < 2 %): "
              f"{'met' if ok else 'NOT met'}", flush=True)
        if f["silhouettes"]:
            sil = f["silhouettes"]
            print(f"      silhouette refinement: {sil['frames']} frames, {sil['pairs']} pairs, "
                  + (f"tangency median {sil['tangency_median_px'][0]:.2f} -> {sil['tangency_median_px'][1]:.2f} px"
                     if "tangency_median_px" in sil else "") + ("" if sil["applied"] else f"; not applied: {sil['reason']}"),
                  flush=True)
    _records.write_record(
        "sfm", title="Structure from motion", merge_on="capture",
        context="the video path's SfM on captures with known poses, compared after a similarity fit "
                "(goal: centres within 2 % of the ring radius, rotations within 2 degrees)",
        rows=[{"capture": name, "registered": f"{f['registered']}/{f['frames']}", "minutes": round(f["seconds"] / 60, 1),
               "centre error max / mean %": f"{f['centre_error_pct']['max']:.2f} / {f['centre_error_pct']['mean']:.2f}",
               "rotation error max / mean deg": f"{f['rotation_error_deg']['max']:.2f} / "
                                                f"{f['rotation_error_deg']['mean']:.2f}"}
              for name, f in figures.items()])
    if args.out:
        fsio.write_json(args.out, {**figures, "load_average": list(os.getloadavg())})
    return 0
