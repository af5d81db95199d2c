"""Real captures end to end without an HDR map: import, reconstruct (lighting estimated), held-out PSNR, contact sheets.

For each capture of the shared data (DTU scan 65 with the dataset's masks, the Middlebury
dino with masks derived from its images, the AliceVision Buddha: four frames, no masks, a
sphere start), the commands a user runs, as child processes:

1. ``import SRC --out OUT/<name>/capture --max-size IMPORT`` (frames downscaled once);
2. ``reconstruct CAPTURE --out OUT/<name>/run --time-budget MINUTES --max-size SIZE
   --track-accuracy --held-out-every K --lighting L`` with every other default: the capture
   has no map, so the lighting is estimated (an environment map fitted with the material, its
   scale fixed by the convention's mean albedo, RUN/environment.exr): ``L`` is ``rig`` for DTU,
   whose studio lamps travel with the camera (its frames are fitted closer under a map fixed to
   the camera than under one fixed to the world: docs/notes/2026-11-28-dtu-fit-ceiling.md),
   ``estimate`` for the others;
   ``--reconstruct-args`` with a ``--lighting`` of its own wins; ``--track-accuracy`` leaves every
   K-th frame out of everything the run fits (K per capture below: 8 where the capture has
   16 frames or more, fewer on the short ones so that two frames are held out);
3. the contact sheet, ``OUT/<name>/contact_sheet.png``: one row per held-out frame and per
   ``--fitted`` fitted frames, with the photo, the run's final display mesh rendered at that
   camera under the lighting the run fitted (backend.lighting.fitted) and the error (x4).

Scores. Each row's PSNR is on sRGB within the frame's mask (the whole frame without one),
the render at SIZE px and ``--spp``, as ``--track-accuracy`` scores (which renders fewer
samples; its last point is printed beside it). The held-out figure is the mean over the
held-out rows. A run that fitted per-frame gains is scored at them (fitted frames at their
own, held-out frames at the gains' median: ``scored_at``). Results: ``OUT/captures.json`` and a printed table.

``--pieces`` runs each capture once per named model instead (``PIECES``): ``base`` with every
real-camera piece off (no per-frame exposure, no camera refinement, the capture's fixed
lighting, no texture stage), each piece alone on top of it, and ``all`` of them together, in
``OUT/<name>/<piece>/``; the record ``captures-pieces`` has one row per capture and piece."""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from .. import variant
from ..capture.images import linear_to_srgb, read_linear_rgb
from ..capture.load import load_capture
from ..geometry.mesh import load_mesh
from ..lighting import exposure, fitted
from ..lighting.modes import MAP_FRAME
from ..metrics.image import psnr, ssim
from ..optimize.views import ViewSet
from ..render.scene import RenderSettings, SceneRenderer
from ..render.views import display_field
from . import _launch, _records
from ._data import SHARED_DATA



@dataclass(frozen=True)
class RealCapture:
    source: str  # under the shared data folder
    held_out_every: int
    about: str
    lighting: str = "estimate"  # reconstruct --lighting: "rig" where the lamps travel with the camera


CAPTURES = {
    "dtu": RealCapture("captures/dtu_scan65", 6,
                       "DTU scan 65: a skull under studio lights, 13 frames, the dataset's masks", "rig"),
    "dino": RealCapture("captures/middlebury_dinoSparseRing/dinoSR_par.txt", 8,
                        "Middlebury dino: 16 frames on a ring, masks derived from the images"),
    "buddha": RealCapture("captures/alicevision_buddha", 2, "AliceVision Buddha: 4 frames, no masks (sphere start)"),
}


BASE = ("--exposure", "off", "--refine-cameras", "off", "--texture-stage", "off")
PIECES = {
    "base": BASE,
    "exposure": ("--exposure", "per-frame", "--refine-cameras", "off", "--texture-stage", "off"),
    "cameras": ("--exposure", "off", "--refine-cameras", "on", "--texture-stage", "off"),
    "lighting": (*BASE, "--lighting", "auto"),
    "texture": ("--exposure", "off", "--refine-cameras", "off", "--texture-stage", "on"),
    "all": ("--exposure", "per-frame", "--refine-cameras", "on", "--texture-stage", "on", "--lighting", "auto"),
}


def add_arguments(parser) -> None:
    parser.add_argument("--out", type=Path, default=Path("bench_captures"), help="folder for the captures and runs")
    parser.add_argument("--captures", default=",".join(CAPTURES), help="which, comma-separated (default: %(default)s)")
    parser.add_argument("--minutes", type=float, default=10.0, help="reconstruct's time budget per capture")
    parser.add_argument("--import-size", type=int, default=400, help="long side of the imported frames, px")
    parser.add_argument("--max-size", type=int, default=128, help="reconstruct's finest image size, px")
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel of the contact sheets' renders")
    parser.add_argument("--fitted", type=int, default=2, help="fitted frames shown beside the held-out ones")
    parser.add_argument("--reconstruct-args", default="", help="further reconstruct options, quoted")
    parser.add_argument("--rerun", action="store_true", help="run again when OUT/<name>/run has a result")
    parser.add_argument("--pieces", default="", help="comma-separated models to compare per capture, of "
                        f"{', '.join(PIECES)} ('all' for every piece together); empty: the defaults once")


def _backend(*args) -> None:
    """``python -m backend ARGS`` as a child process; raises with its last error line."""
    _launch.run(_launch.backend(*args), what=str(args[0]))


def _srgb8(linear: np.ndarray) -> np.ndarray:
    return (np.clip(linear_to_srgb(np.clip(linear, 0, None)), 0, 1) * 255 + 0.5).astype(np.uint8)


def render_rows(capture_dir: Path, run_dir: Path, size: int, spp: int, fitted_rows: int) -> list[dict]:
    """The contact sheet's rows: held-out frames (those the run's report names) first, then up
    to ``fitted_rows`` fitted ones spread over the capture; each with photo, render, PSNR.
    A run that fitted per-frame gains (``--exposure``) is scored at them: a fitted frame's
    render times its own gains, a held-out one's times their median
    (backend.lighting.exposure.scoring_gains)."""
    variant.choose()
    capture = load_capture(capture_dir)
    report = json.loads((run_dir / "report.json").read_text())
    held = set((report.get("accuracy_time") or {}).get("held_out_views") or [])
    display = load_mesh(run_dir / json.loads((run_dir / "snapshot.json").read_text())["mesh"])
    lit = fitted.light_views(capture, fitted.from_run(run_dir))
    lights = {f.name: f.lights for f in lit.frames}
    views = ViewSet(capture, size).views
    others = [v for v in views if v.name not in held]
    picks = sorted({round(i * len(others) / fitted_rows) for i in range(fitted_rows)}) if fitted_rows > 0 else []
    chosen = [v for v in views if v.name in held] + [others[i] for i in picks if i < len(others)]
    renderer = SceneRenderer(display, display_field(display), [v.camera for v in chosen],
                             [lights[v.name] for v in chosen], lit.environment,
                             RenderSettings(spp=spp, max_depth=4, integrator="path"))
    frames = {f.name: f for f in capture.frames}
    gains = exposure.scoring_gains(report.get("exposure"), [v.name for v in chosen])
    rows = []
    for i, v in enumerate(chosen):
        render = renderer.render_numpy(i, seed=i)[..., :3] * gains[v.name]  # the frame's camera response
        photo = capture.camera_response.radiance(read_linear_rgb(frames[v.name].image))
        photo = np.asarray(Image.fromarray(_srgb8(photo)).resize((v.camera.width, v.camera.height), Image.BOX))
        rows.append({"frame": v.name, "held_out": v.name in held, "psnr": float(psnr(render, v.target, v.mask)),
                     "ssim": float(ssim(render, v.target, v.mask)),
                     "photo": photo, "render": render, "target": v.target, "mask": v.mask})
    return rows


def write_sheet(path: Path, rows: list[dict], title: str) -> None:
    """Rows of photo | render | error x4 (sRGB, within the mask), each labelled with its PSNR."""
    h, w = rows[0]["render"].shape[:2]
    label, pad = 14, 4
    sheet = Image.new("RGB", (3 * w + 4 * pad, label + len(rows) * (h + label + pad) + pad), (32, 32, 32))
    draw = ImageDraw.Draw(sheet)
    draw.text((pad, 1), title, fill=(235, 235, 235))
    for r, row in enumerate(rows):
        y = label + r * (h + label + pad) + pad
        kind = "held-out" if row["held_out"] else "fitted"
        draw.text((pad, y), f"{kind} {row['frame']}: {row['psnr']:.2f} dB  (photo | render | error x4)",
                  fill=(255, 210, 120) if row["held_out"] else (200, 200, 200))
        weight = np.ones(row["render"].shape[:2]) if row["mask"] is None else row["mask"]
        error = np.abs(_srgb8(row["render"]).astype(float) - _srgb8(row["target"]).astype(float)) * weight[..., None]
        tiles = [row["photo"], _srgb8(row["render"]), np.clip(4 * error, 0, 255).astype(np.uint8)]
        for c, tile in enumerate(tiles):
            sheet.paste(Image.fromarray(tile[:h, :w]), (pad + c * (w + pad), y + label))
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)


def lighting_args(spec: RealCapture, extra: str) -> list[str]:
    """reconstruct's further arguments: ``extra`` (split), with the capture's ``--lighting``
    unless ``extra`` names one."""
    words = extra.split()
    named = any(w == "--lighting" or w.startswith("--lighting=") for w in words)
    return words if named else ["--lighting", spec.lighting, *words]


def one(name: str, spec: RealCapture, args, piece: str | None = None) -> dict:
    """Import (once per capture), reconstruct, score and draw the sheet of one capture; with
    ``piece``, in ``OUT/<name>/<piece>/`` with that model's options before ``--reconstruct-args``."""
    capture = args.out / name / "capture"
    folder = args.out / name / piece if piece else args.out / name
    run = folder / "run"
    extra = " ".join([*PIECES[piece], args.reconstruct_args]) if piece else args.reconstruct_args
    start = time.perf_counter()
    if not (capture / "capture.json").is_file():
        _backend("import", SHARED_DATA / spec.source, "--out", capture, "--max-size", args.import_size, "--overwrite")
    imported = time.perf_counter()
    if args.rerun or not (run / "report.json").is_file():
        # --overwrite: the folder is the bench's own, and one a stopped bench left has no result
        _backend("reconstruct", capture, "--out", run, "--overwrite", "--time-budget", args.minutes,
                 "--max-size", args.max_size,
                 "--track-accuracy", "--held-out-every", spec.held_out_every,
                 *lighting_args(spec, extra))
    reconstructed = time.perf_counter()
    report = json.loads((run / "report.json").read_text())
    rows = render_rows(capture, run, args.max_size, args.spp, args.fitted)
    held = [r["psnr"] for r in rows if r["held_out"]]
    fit = [r["psnr"] for r in rows if not r["held_out"]]
    held_ssim = [r["ssim"] for r in rows if r["held_out"]]
    used = fitted.from_run(run)
    frame = used.environment.frame if used.environment is not None else None
    lighting = {MAP_FRAME["rig"]: "rig", MAP_FRAME["world+rig"]: "world+rig"}.get(frame, used.model)
    title = (f"{spec.about}; {piece + ', ' if piece else ''}{args.minutes:g} min, lighting {lighting}; "
             f"held-out {np.mean(held):.2f} dB" if held else f"{spec.about}; nothing held out")
    write_sheet(folder / "contact_sheet.png", rows, title)
    points = (report.get("accuracy_time") or {}).get("points") or []
    return {
        "capture": name, "piece": piece, "about": spec.about, "frames": len(load_capture(capture).frames),
        "held_out_every": spec.held_out_every, "held_out_frames": [r["frame"] for r in rows if r["held_out"]],
        "held_out_psnr": float(np.mean(held)) if held else None,
        "held_out_psnr_each": {r["frame"]: round(r["psnr"], 3) for r in rows if r["held_out"]},
        "held_out_ssim": float(np.mean(held_ssim)) if held_ssim else None,
        "fitted_psnr": float(np.mean(fit)) if fit else None,
        "scored_at": exposure.scoring_note(report.get("exposure")),
        "tracked_last_psnr": points[-1]["psnr"] if points else None,
        "lighting": lighting, "environment_map": (run / "environment.exr").is_file(),
        "lighting_choice": report.get("lighting_choice"), "cameras_refined": report.get("cameras_refined"),
        "faces": report["result"]["faces"], "genus": report["result"]["genus"],
        "minutes": {"import": round((imported - start) / 60, 2), "reconstruct": round((reconstructed - imported) / 60, 2),
                    "sheet": round((time.perf_counter() - reconstructed) / 60, 2)},
        "sheet": str(folder / "contact_sheet.png"), "size": args.max_size, "spp": args.spp,
    }


def run(args) -> int:
    names = [n.strip() for n in args.captures.split(",") if n.strip()]
    unknown = [n for n in names if n not in CAPTURES]
    if unknown:
        print(f"error: unknown capture {unknown[0]!r}: give some of {', '.join(CAPTURES)}", file=sys.stderr)
        return 2
    missing = [SHARED_DATA / CAPTURES[n].source for n in names if not (SHARED_DATA / CAPTURES[n].source).exists()]
    if missing:
        print(f"error: {missing[0]}: shared data not found; set SFT_SHARED_DATA to the data folder", file=sys.stderr)
        return 2
    pieces = [p.strip() for p in args.pieces.split(",") if p.strip()]
    bad = [p for p in pieces if p not in PIECES]
    if bad:
        print(f"error: unknown piece {bad[0]!r}: give some of {', '.join(PIECES)}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    results, failed = [], 0
    for name in names:
        for piece in pieces or [None]:
            print(f"[{name}{'/' + piece if piece else ''}] {CAPTURES[name].about}", flush=True)
            try:
                results.append(one(name, CAPTURES[name], args, piece))
            except RuntimeError as err:
                failed += 1
                results.append({"capture": name, "piece": piece, "error": str(err)})
                print(f"[{name}] {err}", flush=True)
    (args.out / "captures.json").write_text(json.dumps(results, indent=1))
    if pieces:
        _write_pieces_record(results, args)
    else:
        _write_record(results, args)
    _print_table(results)
    print(f"contact sheets and captures.json in {args.out}")
    return 1 if failed else 0


def _fmt(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.2f}"


def _write_pieces_record(results: list[dict], args) -> None:
    _records.write_record(
        "captures-pieces", title="Real captures: what each real-camera piece adds", merge_on="run",
        context=f"held-out PSNR/SSIM within the masks, {args.minutes:g} min at {args.max_size} px per run; base: no "
                "exposure, no camera refinement, the capture's fixed lighting, no texture stage; each piece alone on "
                "base; all: every piece",
        rows=[{"run": f"{r['capture']}/{r['piece']}", "commit": _records.code_version(),
               "lighting": r["lighting"], "faces": r["faces"],
               "held-out dB": round(r["held_out_psnr"], 2) if r["held_out_psnr"] is not None else None,
               "held-out SSIM": round(r["held_out_ssim"], 3) if r["held_out_ssim"] is not None else None,
               "fitted-view dB": round(r["fitted_psnr"], 2) if r["fitted_psnr"] is not None else None,
               "reconstruct min": r["minutes"]["reconstruct"]} for r in results if "error" not in r],
        show=["run", "lighting", "held-out dB", "held-out SSIM", "fitted-view dB"])  # sheets: OUT/<name>/<piece>/


def _named_lighting(extra: str) -> str | None:
    """The ``--lighting`` that ``--reconstruct-args`` names, or None."""
    words = extra.split()
    for k, w in enumerate(words):
        if w.startswith("--lighting="):
            return w.split("=", 1)[1]
        if w == "--lighting" and k + 1 < len(words):
            return words[k + 1]
    return None


def _write_record(results: list[dict], args) -> None:
    if _named_lighting(args.reconstruct_args) is not None:
        # a lighting model compared on a capture: its own record, one row per capture and model, so
        # the captures' default table keeps its figures
        _records.write_record(
            "captures-lighting", title="Real captures: one lighting model against another", merge_on="run",
            context=f"photographs imported at {args.import_size} px and reconstructed in {args.minutes:g} min at "
                    f"{args.max_size} px under the named --lighting; PSNR on sRGB within the masks",
            rows=[{"run": f"{r['capture']}/{r['lighting']}", "frames": r["frames"],
                   "held out": len(r["held_out_frames"]), "faces": r["faces"],
                   "held-out dB": round(r["held_out_psnr"], 2) if r["held_out_psnr"] is not None else None,
                   "fitted-view dB": round(r["fitted_psnr"], 2) if r["fitted_psnr"] is not None else None,
                   "reconstruct min": r["minutes"]["reconstruct"]} for r in results if "error" not in r])
        return  # its contact sheets stay in OUT: the captures' default sheets are the docs' plots
    _records.write_record(
        "captures", title="Real captures", merge_on="capture",
        context=f"photographs imported at {args.import_size} px and reconstructed in {args.minutes:g} min at "
                f"{args.max_size} px with the lighting estimated; PSNR on sRGB within the masks",
        rows=[{"capture": r["capture"], "frames": r["frames"], "held out": len(r["held_out_frames"]),
               "lighting": r["lighting"], "faces": r["faces"], "held-out dB": round(r["held_out_psnr"], 2)
               if r["held_out_psnr"] is not None else None,
               "fitted-view dB": round(r["fitted_psnr"], 2) if r["fitted_psnr"] is not None else None,
               "reconstruct min": r["minutes"]["reconstruct"]} for r in results if "error" not in r],
        plots=[r["sheet"] for r in results if "error" not in r])


def _print_table(results: list[dict]) -> None:
    print(f"\n{'capture':16} {'frames':>6} {'held out':>9} {'held-out PSNR':>14} {'fitted PSNR':>12} "
          f"{'tracked':>8} {'lighting':>9} {'faces':>6} {'minutes':>8}")
    for r in results:
        if "error" in r:
            print(f"{r['capture']:16} failed: {r['error']}")
            continue
        label = f"{r['capture']}/{r['piece']}" if r.get("piece") else r["capture"]
        print(f"{label:16} {r['frames']:6d} {len(r['held_out_frames']):9d} {_fmt(r['held_out_psnr']):>14} "
              f"{_fmt(r['fitted_psnr']):>12} {_fmt(r['tracked_last_psnr']):>8} {str(r['lighting']):>9} "
              f"{str(r['faces']):>6} {sum(r['minutes'].values()):8.1f}")
