"""Auto-exposure: a phone-style capture whose exposure and white balance drift over the frames, against the same capture without drift.

``python -m backend bench exposure [--minutes M] [--drift STOPS] [--white-balance STOPS]
[--without-fit] --out OUT`` renders the built-in textured blob (``--views`` views at
``--resolution`` px, two point lights per camera, held-out views) twice with the same seed:
as it is (``plain``) and with ``synth --exposure-drift STOPS --white-balance-drift STOPS``
(``drift``: every frame times its own smooth gain, backend.synth.drift; the true gains in
gt/exposure.json, in the fit's gauge). Both run ``reconstruct --material staged --time-budget
M --exposure auto``: the drift capture's capture.json marks its frames as auto-exposed, so
auto fits per-frame gains there and keeps one exposure on the plain one (the report's
``exposure.model`` says which). ``--without-fit`` adds the drift capture with ``--exposure
off``: what the drift costs when nothing takes it up.

Each row: F1@0.01 (per cent) and Chamfer-L1 against the truth; albedo RMSE after the best
global scale (one factor for all channels, least squares at corresponding surface points)
and after one factor per channel; held-out PSNR (the truth's held-out views carry no drift:
they are scored at gain 1, the gauge); and the fitted gains against the true ones, both in
the gauge: the largest and the RMS error in stops, and the share of the drift's variance
(in log-gain) they leave (``gain residual``: 0 when recovered exactly, 1 when not at all), and the share of the swing
recovered (``gain recovered``: the least-squares slope of fitted on true log-gains; 1 exact,
below 1 where the texture took up part of the drift or the prior pulled it in).
Targets: the drift run's F1@0.01 within 1 point (0.01 as a fraction) of the plain run's,
its albedo RMSE after the global scale at most 0.05. Writes the ``exposure`` record."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..geometry.mesh import load_mesh
from ..metrics import geometry as geo
from ..metrics.evaluate import evaluate, prediction_path
from . import _launch, _records

F1_POINTS = 1.0  # the drift run's F1@0.01 (per cent) at most this far below the plain run's
ALBEDO_RMSE = 0.05  # the drift run's albedo RMSE after the best global scale at most this


def add_arguments(parser) -> None:
    parser.add_argument("--out", type=Path, default=Path("bench_exposure"), help="folder for the captures and runs")
    parser.add_argument("--minutes", type=float, default=3.0, help="each run's time budget (default: %(default)s)")
    parser.add_argument("--drift", type=float, default=0.5, help="auto-exposure swing, +-stops (default: %(default)s)")
    parser.add_argument("--white-balance", type=float, default=0.2,
                        help="white-balance swing (temperature and tint), +-stops (default: %(default)s)")
    parser.add_argument("--views", type=int, default=16)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=64, help="the captures' samples per pixel")
    parser.add_argument("--without-fit", action="store_true", help="also run the drift capture with --exposure off")
    parser.add_argument("--rerun", action="store_true", help="run again where a run folder has a report")


def gain_errors(fitted: dict, truth: dict) -> dict:
    """Fitted against true per-frame gains ({frame: [r, g, b]}, both in the gauge) over the
    frames both name: largest and RMS error of log2 g (stops), and the residual share of the
    true log-gains' variance."""
    names = [n for n in truth if n in fitted]
    if not names:
        return {"frames": 0}
    f = np.log2(np.array([fitted[n] for n in names], np.float64))
    t = np.log2(np.array([truth[n] for n in names], np.float64))
    err = f - t
    spread = float((t ** 2).mean())
    slope = float((f * t).sum() / (t ** 2).sum()) if spread > 0 else None
    return {"frames": len(names), "max stops": round(float(np.abs(err).max()), 4),
            "recovered": round(slope, 3) if slope is not None else None,
            "rms stops": round(float(np.sqrt((err ** 2).mean())), 4),
            "residual": round(float((err ** 2).mean() / spread), 4) if spread > 0 else None,
            "true spread stops": round(float(np.sqrt(spread)), 4)}


def global_scale_rmse(pred: np.ndarray, truth: np.ndarray) -> float:
    """RMSE of ``pred`` albedo after the one least-squares factor s = <p, t> / <p, p> for all channels."""
    p, t = np.asarray(pred, np.float64), np.asarray(truth, np.float64)
    s = float((p * t).sum() / max(float((p * p).sum()), 1e-12))
    return float(np.sqrt(((s * p - t) ** 2).mean()))


def _albedo_mesh(run: Path):
    """The mesh evaluate scores albedo on: result.ply when it carries colours, else the display mesh."""
    result = load_mesh(prediction_path(run))
    if result.vertex_colors is not None:
        return result
    return load_mesh(run / json.loads((run / "snapshot.json").read_text())["mesh"])


def score(run: Path, capture: Path) -> dict:
    """One run's row (see the module)."""
    report = evaluate(run, capture, samples=50_000)
    own = json.loads((run / "report.json").read_text())
    exposure = own.get("exposure") or {}
    truth_doc = load_capture_truth(capture)
    gt = load_mesh(capture / "gt" / "mesh.ply")
    pa, ga = geo.corresponding_albedo(_albedo_mesh(run), gt, 50_000, 0)
    row = {"F1@0.01": round(report["geometry"]["f1@0.01"], 2), "Chamfer-L1": round(report["geometry"]["chamfer_l1"], 5),
           "albedo RMSE (global scale)": round(global_scale_rmse(pa, ga), 4),
           "albedo RMSE (per channel)": round(report.get("albedo", {}).get("rmse_scaled", float("nan")), 4),
           "held-out dB": round(report.get("views", {}).get("held_out", {}).get("psnr", float("nan")), 2),
           "gains": exposure.get("model", "off"), "solves": exposure.get("solves", 0),
           "steps": own["result"]["iterations"]}
    if truth_doc is not None:
        errors = gain_errors(exposure.get("gains") or {n: [1.0, 1.0, 1.0] for n in truth_doc["gains"]},
                             truth_doc["gains"])
        row.update({f"gain {k}": v for k, v in errors.items() if k != "frames"})
    return row


def load_capture_truth(capture: Path) -> dict | None:
    """The capture's true gains document (ground_truth.exposure), or None without drift."""
    doc = json.loads((capture / "capture.json").read_text())
    rel = (doc.get("ground_truth") or {}).get("exposure")
    return json.loads((capture / rel).read_text()) if rel else None


def _synth(out: Path, args, drift: float, white_balance: float) -> None:
    if (out / "capture.json").is_file():
        return
    _launch.run(_launch.backend("synth", "--out", out, "--overwrite", "--mesh", "blob", "--views", args.views,
                                "--resolution", args.resolution, "--lighting", "points", "--albedo", "pattern",
                                "--spp", args.spp, "--held-out", 2, "--seed", 0, "--exposure-drift", drift,
                                "--white-balance-drift", white_balance), what="synth")


def run(args) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    plain, drifting = args.out / "plain", args.out / "drift"
    _synth(plain, args, 0.0, 0.0)
    _synth(drifting, args, args.drift, args.white_balance)
    runs = [("plain", plain, "auto"), ("drift", drifting, "auto")]
    if args.without_fit:
        runs.append(("drift, gains off", drifting, "off"))
    rows = []
    for label, capture, mode in runs:
        folder = args.out / ("run_" + label.replace(", ", "_").replace(" ", "_"))
        if args.rerun or not (folder / "report.json").is_file():
            _launch.run(_launch.backend("reconstruct", capture, "--out", folder, "--overwrite", "--material", "staged",
                                        "--time-budget", args.minutes, "--exposure", mode),
                        log=args.out / f"{folder.name}.log", what="reconstruct")
        row = {"capture": label, "exposure": mode, **score(folder, capture)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    base, drift = rows[0], rows[1]
    df1 = drift["F1@0.01"] - base["F1@0.01"]
    scalars = {"drift stops": args.drift, "white balance stops": args.white_balance, "minutes": args.minutes,
               "F1 drift - plain (points)": round(df1, 2), "F1 target met": bool(df1 >= -F1_POINTS),
               "albedo target met": bool(drift["albedo RMSE (global scale)"] <= ALBEDO_RMSE)}
    print(json.dumps(scalars), flush=True)
    _records.write_record(
        "exposure", title="Auto-exposure drift",
        context=(f"the textured blob ({args.views} views at {args.resolution} px, point lights), frames with a "
                 f"+-{args.drift:g}-stop exposure and +-{args.white_balance:g}-stop white-balance drift against "
                 f"the same frames without; --material staged, {args.minutes:g} min, --exposure as named"),
        rows=rows, scalars=scalars,
        command=(f"python -m backend bench exposure --minutes {args.minutes:g} --drift {args.drift:g} "
                 f"--white-balance {args.white_balance:g} --views {args.views} --resolution {args.resolution}"
                 + (" --without-fit" if args.without_fit else "") + " --out OUT"))
    return 0
