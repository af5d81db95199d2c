"""Automatic masks: orbit videos rendered with Cycles, masks made from SfM, IoU against the true masks.

Each scene is a video rendered by ``scripts/render_orbit.py`` (a child process, cached in
``--out/<scene>``): by default the crane cow on a textured ground plane (the ground is in the
frames, not in the true masks) and the Stanford bunny under the map alone. Every video frame
is kept; SfM runs on the frames without masks (``backend.video.sfm``), the masks are made
from its result (``backend.masks``: the points the orbit circles, GrabCut, the visual hull as
a check), and each kept frame's mask is compared with the render's own mask (IoU, object
pixels above half). Dropped frames count in their own column. Goal: mean IoU >= 0.95."""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np

from ..capture.images import read_mask
from ..masks import MaskOptions, make_masks
from ..masks.consistency import iou
from ..video.frames import open_source
from ..video.sfm import SfmOptions, solve
from . import _launch, _records
from ._data import SHARED_DATA as SHARED

ROOT = Path(__file__).resolve().parents[2]
# name: (mesh, up axis, ground plane)
SCENES = {
    "cow-on-ground": (SHARED / "meshes" / "crane" / "spot" / "spot.obj", "y", True),
    "bunny": (SHARED / "meshes" / "stanford" / "bunny_watertight.obj", "y", False),
    "sphere": (None, "y", False),
}
GOAL_IOU = 0.95


def add_arguments(parser):
    parser.add_argument("--out", type=Path, default=Path("bench_masks"), help="folder for the videos and frames")
    parser.add_argument("--scenes", default="cow-on-ground,bunny", help=f"comma-separated, of {sorted(SCENES)}")
    parser.add_argument("--frames", type=int, default=24, help="video frames over one orbit")
    parser.add_argument("--size", default="640x360", help="video WIDTHxHEIGHT (SIFT wants 512 px or more)")
    parser.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel")
    parser.add_argument("--distance", type=float, default=2.4,
                        help="orbit radius (the object is about 1 across: it stays inside the frames)")
    parser.add_argument("--seed", type=int, default=0)


def render(args, scene: str) -> Path:
    """The scene's video folder, rendered unless one with the same settings is there."""
    mesh, up, ground = SCENES[scene]
    folder = args.out / scene
    wanted = {"scene": scene, "frames": args.frames, "size": args.size, "samples": args.samples, "seed": args.seed,
              "distance": args.distance}
    stamp = folder / "settings.json"
    if stamp.is_file() and json.loads(stamp.read_text()) == wanted and (folder / "truth.json").is_file():
        return folder
    cmd = [ROOT / "scripts" / "render_orbit.py", "--out", folder, "--frames", args.frames, "--size", args.size,
           "--samples", args.samples, "--denoise", "none", "--seed", args.seed, "--up", up,
           "--distance", args.distance]
    cmd += ["--mesh", mesh] if mesh is not None else []
    cmd += ["--ground"] if ground else []
    _launch.run(_launch.python(*cmd), what="render_orbit.py")
    stamp.write_text(json.dumps(wanted))
    return folder


def measure(folder: Path, work: Path, options: MaskOptions | None = None) -> dict:
    """SfM and automatic masks of every frame of ``folder/orbit.mp4``; IoU against its masks."""
    from PIL import Image

    source = open_source(folder / "orbit.mp4")
    shutil.rmtree(work, ignore_errors=True)  # a COLMAP database left there would be added to
    (work / "frames").mkdir(parents=True)
    frames, paths = {}, []
    for i, rgb in source.frames():
        name = f"{i:04d}"
        frames[name] = rgb
        paths.append(work / "frames" / f"{name}.png")
        Image.fromarray(rgb).save(paths[-1])
    start = time.perf_counter()
    sfm = solve(paths, work / "sfm", SfmOptions())
    sfm_seconds = time.perf_counter() - start
    report = make_masks({n: frames[n] for n in sfm.poses}, sfm, options)
    scores = {n: iou(m, read_mask(folder / "masks" / f"{n}.png")) for n, m in report.masks.items()}
    values = np.array(list(scores.values()))
    return {"frames": len(frames), "registered": sfm.registered, "kept": len(report.masks),
            "dropped": len(report.dropped), "mean_iou": float(values.mean()), "min_iou": float(values.min()),
            "sfm_s": sfm_seconds, "masks_s": report.seconds, "region": report.region, "per_frame": scores,
            "dropped_frames": report.dropped}


def run(args) -> int:
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = sorted(set(scenes) - set(SCENES))
    if unknown:
        raise SystemExit(f"unknown scenes {unknown}: choose from {sorted(SCENES)}")
    rows = []
    for scene in scenes:
        folder = render(args, scene)
        result = measure(folder, args.out / f"{scene}-work")
        print(f"  {scene}: mean IoU {result['mean_iou']:.4f} (min {result['min_iou']:.4f}), kept {result['kept']} "
              f"of {result['frames']}, SfM {result['sfm_s']:.0f} s, masks {result['masks_s']:.0f} s", flush=True)
        rows.append({"scene": scene, "frames": result["frames"], "registered": result["registered"],
                     "kept": result["kept"], "dropped": result["dropped"], "mean IoU": round(result["mean_iou"], 4),
                     "min IoU": round(result["min_iou"], 4), "SfM s": round(result["sfm_s"], 1),
                     "masks s": round(result["masks_s"], 1)})
    mean = float(np.mean([r["mean IoU"] for r in rows]))
    path = _records.write_record(
        "masks", title="Automatic masks",
        context=f"Cycles orbit videos, {args.frames} frames {args.size}, {args.samples} spp; SfM without masks, "
                f"masks from the object points (GrabCut, visual hull check) against the rendered masks",
        rows=rows, scalars={"mean IoU": round(mean, 4), "goal": GOAL_IOU, "met": bool(mean >= GOAL_IOU)},
        show=["scene", "frames", "kept", "mean IoU", "min IoU", "SfM s", "masks s"])
    print(f"mean IoU {mean:.4f} (goal {GOAL_IOU}); record {path}")
    return 0
