"""Automatic masks: orbit videos rendered with Cycles, masks made from SfM, IoU against the true masks.

Each scene is a video rendered by ``scripts/render_orbit.py`` (a child process, cached in
``--out/<scene>``): by default the crane cow on a textured ground plane (the ground is in the
frames, not in the true masks) and the Stanford bunny under the map alone. Every video frame
is kept; SfM runs on the frames without masks (``backend.video.sfm``), the masks are made
from its result (``backend.masks``: the points the orbit circles, GrabCut, the visual hull as
a check), and each kept frame's mask is compared with the render's own mask (IoU, object
pixels above half). Dropped frames count in their own column. Goal: mean IoU >= 0.95.

What the masks cost (``--f1-scene``, the first scene by default; ``--f1-minutes 0`` skips it):
two captures of that scene on SfM's cameras (the same for both, no silhouette refinement, so
only the masks differ), one with the automatic masks of the kept frames, one with the true
masks of the same frames, each reconstructed with the same short budget; the result is scored
against the truth after the similarity of the camera centres and ICP (as ``bench realworld``
scores), F1@0.01 in the truth's normalised frame. Goal: the automatic masks' F1 within 0.03
(3 points of the percentage) of the true masks'.

The SfM result is kept beside the frames (``--out/<scene>-work/sfm.npz``, with the seconds it
took) and reused while the video is unchanged, so changes to the masks are measured on the
same cameras; ``--fresh-sfm`` solves again."""

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
from ..video.sfm import SfmOptions, SfmResult, solve
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
GOAL_F1_GAP = 3.0  # F1@0.01 points (percent): 0.03 of the unit score
MAP = SHARED / "envmaps" / "venice_sunset_1k.hdr"  # render_orbit.py's default map


def add_arguments(parser):
    parser.add_argument("--out", type=Path, default=Path("bench_masks"), help="folder for the videos and frames")
    parser.add_argument("--scenes", default="cow-on-ground,bunny", help=f"comma-separated, of {sorted(SCENES)}")
    parser.add_argument("--frames", type=int, default=24, help="video frames over one orbit")
    parser.add_argument("--size", default="640x360", help="video WIDTHxHEIGHT (SIFT wants 512 px or more)")
    parser.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel")
    parser.add_argument("--distance", type=float, default=2.4,
                        help="orbit radius (the object is about 1 across: it stays inside the frames)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fresh-sfm", action="store_true", help="solve SfM again instead of reusing the cached result")
    parser.add_argument("--ground-below", type=float, default=None,
                        help="masks: sure background where the ground's photo-consistency difference is below this "
                             "(0..255; MaskOptions.ground_below)")
    parser.add_argument("--object-above", type=float, default=MaskOptions().object_above,
                        help="masks: sure foreground where it is above this (MaskOptions.object_above; a "
                             "negative value: not used)")
    parser.add_argument("--f1-scene", default=None, help="scene whose reconstruct F1 is compared, automatic against "
                                                         "true masks (default: the first scene)")
    parser.add_argument("--f1-minutes", type=float, default=1.0,
                        help="reconstruct time budget of each of the two runs (0: no F1 comparison)")
    parser.add_argument("--f1-size", type=int, default=96, help="reconstruct --max-size of the two runs")


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
           "--distance", args.distance, "--env", MAP]
    cmd += ["--mesh", mesh] if mesh is not None else []
    cmd += ["--ground"] if ground else []
    _launch.run(_launch.python(*cmd), what="render_orbit.py")
    stamp.write_text(json.dumps(wanted))
    return folder


def _save_sfm(path: Path, sfm, stamp: str) -> None:
    names = [n for n in sfm.names if n in sfm.poses]
    meta = {k: getattr(sfm, k) for k in ("names", "width", "height", "fx", "fy", "cx", "cy", "distortion",
                                          "reprojection_error_px", "method", "seconds", "silhouettes")}
    meta.update(posed=names, stamp=stamp)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, meta=np.array(json.dumps(meta, default=float)), poses=np.stack([sfm.poses[n] for n in names]),
             points=np.asarray(sfm.points, np.float64), observations=np.asarray(sfm.observations, np.float64))
    tmp.replace(path)


def _load_sfm(path: Path, stamp: str):
    if not path.is_file():
        return None
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
        if meta.pop("stamp") != stamp:
            return None
        poses = dict(zip(meta.pop("posed"), data["poses"]))
        return SfmResult(poses=poses, points=data["points"], observations=data["observations"], **meta)


def measure(folder: Path, work: Path, options: MaskOptions | None = None, fresh_sfm: bool = False) -> dict:
    """SfM (cached in ``work``) and automatic masks of every frame of ``folder/orbit.mp4``; IoU against its masks."""
    from PIL import Image

    source = open_source(folder / "orbit.mp4")
    cache = work / "sfm.npz"
    stamp = (folder / "settings.json").read_text() if (folder / "settings.json").is_file() else ""
    sfm = None if fresh_sfm else _load_sfm(cache, stamp)
    if sfm is None:
        shutil.rmtree(work, ignore_errors=True)  # a COLMAP database left there would be added to
    (work / "frames").mkdir(parents=True, exist_ok=True)
    frames, paths = {}, []
    for i, rgb in source.frames():
        name = f"{i:04d}"
        frames[name] = rgb
        paths.append(work / "frames" / f"{name}.png")
        if sfm is None:
            Image.fromarray(rgb).save(paths[-1])
    if sfm is None:
        start = time.perf_counter()
        sfm = solve(paths, work / "sfm", SfmOptions())
        sfm.seconds["bench_total"] = time.perf_counter() - start
        _save_sfm(cache, sfm, stamp)
    sfm_seconds = sfm.seconds.get("bench_total", float(sum(sfm.seconds.values())))
    report = make_masks({n: frames[n] for n in sfm.poses}, sfm, options)
    truth = {n: read_mask(folder / "masks" / f"{n}.png") for n in report.masks}
    scores = {n: iou(m, truth[n]) for n, m in report.masks.items()}
    values = np.array(list(scores.values()))
    return {"frames": len(frames), "registered": sfm.registered, "kept": len(report.masks),
            "dropped": len(report.dropped), "mean_iou": float(values.mean()), "min_iou": float(values.min()),
            "sfm_s": sfm_seconds, "masks_s": report.seconds, "region": report.region, "per_frame": scores,
            "dropped_frames": report.dropped, "sfm": sfm, "frames_rgb": frames, "masks": report.masks,
            "true_masks": truth}


def write_capture(out: Path, sfm, frames: dict[str, np.ndarray], masks: dict[str, np.ndarray]) -> Path:
    """A capture in ``out`` of the frames of ``masks`` with SfM's cameras and those masks (the
    map at rotation 0, strength 1: the same placeholder for every capture compared)."""
    from PIL import Image

    # only the F1 comparison writes captures: the mask-only bench loads none of this
    from ..capture.convert import convert
    from ..capture.format import save_capture
    from ..capture.images import write_mask
    from ..capture.model import Environment
    from ..video.inputs import _scene_capture

    shutil.rmtree(out, ignore_errors=True)
    work = out / ".work"
    (work / "frames").mkdir(parents=True)
    (work / "masks").mkdir()
    names = sorted(masks)
    for n in names:
        Image.fromarray(frames[n]).save(work / "frames" / f"{n}.png")
        write_mask(work / "masks" / f"{n}.png", masks[n])
    capture = _scene_capture(sfm, names, [int(n) for n in names], work, Environment(MAP), work / "masks")
    written = convert(capture, out, None)
    save_capture(written)
    shutil.rmtree(work)
    return out


def reconstruct_f1(capture: Path, run_dir: Path, orbit: Path, minutes: float, size: int) -> dict:
    """``reconstruct`` of ``capture`` (constant material, the capture's map, cameras kept) and
    its F1@0.01 against ``orbit/truth.ply`` after the camera-centre similarity and ICP."""
    # only the F1 comparison scores meshes: the mask-only bench loads none of this
    from ..geometry.mesh import load_mesh
    from ..metrics.geometry import align_by_icp, align_similarity, geometry_metrics

    start = time.perf_counter()
    _launch.run(_launch.python("-m", "backend", "reconstruct", capture, "--out", run_dir, "--overwrite",
                               "--time-budget", f"{minutes:g}", "--max-size", size, "--material", "constant",
                               "--lighting", "captured", "--refine-cameras", "off"), what="reconstruct")
    seconds = time.perf_counter() - start
    truth = json.loads((orbit / "truth.json").read_text())
    doc = json.loads((capture / "capture.json").read_text())
    ours = np.array([np.array(f["camera"]["camera_to_world"])[:3, 3] for f in doc["frames"]])
    theirs = np.array([np.array(truth["camera_to_world"][int(f["name"])])[:3, 3] for f in doc["frames"]])
    gt = load_mesh(orbit / "truth.ply")
    result = load_mesh(run_dir / "result.ply").transformed(align_similarity(ours, theirs))
    metrics = geometry_metrics(result.transformed(align_by_icp(result, gt)), gt)
    return {"f1": float(metrics["f1@0.01"]), "chamfer_l1": float(metrics["chamfer_l1"]), "seconds": seconds}


def run(args) -> int:
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = sorted(set(scenes) - set(SCENES))
    if unknown:
        raise SystemExit(f"unknown scenes {unknown}: choose from {sorted(SCENES)}")
    f1_scene = args.f1_scene or scenes[0]
    if args.f1_minutes > 0 and f1_scene not in scenes:
        raise SystemExit(f"--f1-scene {f1_scene} is not among --scenes {args.scenes}: add it, or pass --f1-minutes 0")
    rows, f1 = [], {}
    for scene in scenes:
        folder = render(args, scene)
        options = MaskOptions(ground_below=args.ground_below,
                              object_above=args.object_above if args.object_above is not None and
                              args.object_above >= 0 else None)
        result = measure(folder, args.out / f"{scene}-work", options, fresh_sfm=args.fresh_sfm)
        if args.f1_minutes > 0 and scene == f1_scene:
            for kind, masks in (("true", result["true_masks"]), ("automatic", result["masks"])):
                capture = write_capture(args.out / f"{scene}-f1" / f"capture-{kind}", result["sfm"],
                                        result["frames_rgb"], masks)
                f1[kind] = reconstruct_f1(capture, args.out / f"{scene}-f1" / f"run-{kind}", folder,
                                          args.f1_minutes, args.f1_size)
                print(f"  {scene}, {kind} masks: reconstruct F1@0.01 {f1[kind]['f1']:.1f}, Chamfer-L1 "
                      f"{f1[kind]['chamfer_l1']:.5f} ({f1[kind]['seconds']:.0f} s)", flush=True)
        print(f"  {scene}: mean IoU {result['mean_iou']:.4f} (min {result['min_iou']:.4f}), kept {result['kept']} "
              f"of {result['frames']}, SfM {result['sfm_s']:.0f} s, masks {result['masks_s']:.0f} s", flush=True)
        rows.append({"scene": scene, "frames": result["frames"], "registered": result["registered"],
                     "kept": result["kept"], "dropped": result["dropped"], "mean IoU": round(result["mean_iou"], 4),
                     "min IoU": round(result["min_iou"], 4), "SfM s": round(result["sfm_s"], 1),
                     "masks s": round(result["masks_s"], 1)})
    mean = float(np.mean([r["mean IoU"] for r in rows]))
    scalars = {"mean IoU": round(mean, 4), "goal": GOAL_IOU, "met": bool(mean >= GOAL_IOU)}
    if f1:
        gap = f1["true"]["f1"] - f1["automatic"]["f1"]
        scalars.update({"F1 scene": f1_scene, "F1@0.01 true masks": round(f1["true"]["f1"], 2),
                        "F1@0.01 automatic masks": round(f1["automatic"]["f1"], 2), "F1 gap": round(gap, 2),
                        "F1 gap goal": GOAL_F1_GAP, "F1 met": bool(gap <= GOAL_F1_GAP),
                        "reconstruct minutes": args.f1_minutes, "reconstruct max size": args.f1_size})
        print(f"F1@0.01 ({f1_scene}): true masks {f1['true']['f1']:.1f}, automatic {f1['automatic']['f1']:.1f}, "
              f"gap {gap:.1f} (goal <= {GOAL_F1_GAP:g})")
    path = _records.write_record(
        "masks", title="Automatic masks",
        context=f"Cycles orbit videos, {args.frames} frames {args.size}, {args.samples} spp; SfM without masks, "
                f"masks from the object points (GrabCut, re-seeded by the strict visual hull, hull check) against the rendered masks",
        rows=rows, scalars=scalars,
        show=["scene", "frames", "kept", "mean IoU", "min IoU", "SfM s", "masks s"])
    print(f"mean IoU {mean:.4f} (goal {GOAL_IOU}); record {path}")
    return 0
