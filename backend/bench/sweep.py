"""Accuracy against time: reconstruct benchmark scenes over a grid of settings, report the Pareto fronts.

``python -m backend bench sweep [--grid smoke|quick|full] [--scenes dragon,blob_env,corner,armadillo_env,video]``
synthesises each scene once (cached in ``OUT/scenes``), then runs ``python -m backend
reconstruct`` as a child process for every setting of the grid and records: wall-clock
seconds (the median over repeats for runs shorter than ``--repeat-under``; each figure below
is then the median over the runs too), the child's
CPU seconds and peak memory (``os.wait4`` rusage), the 1-minute load average before and
after, Chamfer-L1 and F1@0.01 (from the run's report), and novel-view and relit PSNR (the
result rendered with its estimated material at the capture's held-out and relit cameras,
scored with :func:`backend.metrics.image.image_metrics` on the object's masks). Results
accumulate in ``OUT/results.jsonl``; a setting already measured there is not run again
(``--rerun`` forces it). Finally the report (``report.md``, ``pareto_<scene>.png``,
``results.json``) is written to ``--report`` (default: bench/ at the repository root).

The grid's settings change the knobs of the ``reconstruct`` command one at a time around the
Draft preset: image size (--max-size), samples per pixel (--spp), bounces (prb_projective
with --max-depth; 1 bounce = direct_projective), views per step, the iteration cap and time
budget, and the face budget (--initial-faces, --max-levels); the presets themselves are
part of the grid. ``--ray [ADDRESS]`` runs the same runs as Ray tasks (``bench/_ray.py``)."""

from __future__ import annotations

import dataclasses
import json
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import fsio, variant
from ..capture.images import read_linear_rgb, read_mask
from ..capture.load import load_capture
from ..errors import InputError
from ..events import Emitter
from ..geometry.mesh import Mesh, load_mesh
from ..metrics.image import image_metrics
from ..optimize.config import ReconstructConfig
from ..planning.presets import PRESETS
from ..render.views import render_views
from . import _all, _launch, _records, _report
from ._machine import REPO, code_version, machine, machine_line  # noqa: F401  (bench/effects imports them from here)
from ._ray import require_ray, run_tasks
from ._sweep_scenes import SCENES, ensure


@dataclass(frozen=True)
class Setting:
    """A preset plus ``reconstruct`` options (None: the preset's value)."""

    name: str
    preset: str = "draft"
    max_size: int | None = None
    spp: int | None = None
    max_depth: int | None = None  # path vertices for prb_projective; None: the preset's integrator
    views_per_step: int | None = None
    iterations: int | None = None
    time_budget: float | None = None  # minutes
    initial_faces: int | None = None
    max_levels: int | None = None
    init: str | None = None  # None: by the capture (carving with masks)
    material: str = "constant"  # the sweep scores one constant material; calibrate: its --material

    def args(self) -> list[str]:
        """The ``reconstruct`` options of this setting."""
        out = ["--preset", self.preset, "--material", self.material]
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name in ("name", "preset", "max_depth", "material") or value is None:
                continue
            out += ["--" + f.name.replace("_", "-"), str(value)]
        if self.max_depth is not None:
            out += ["--integrator", "prb_projective", "--max-depth", str(self.max_depth)]
        return out

    def knobs(self) -> dict:
        """The effective value of every knob: defaults, then the preset, then the options."""
        c = dataclasses.asdict(ReconstructConfig())
        c.update(PRESETS[self.preset])
        c.update({k: v for k, v in dataclasses.asdict(self).items()
                  if k not in ("name", "preset", "time_budget", "material") and v is not None})
        if self.max_depth is not None:
            c["integrator"] = "prb_projective"
        bounces = 1 if c["integrator"] == "direct_projective" else c["max_depth"] - 1
        return {"max_size": c["max_size"], "spp": c["spp"], "bounces": bounces,
                "views_per_step": c["views_per_step"], "iterations": c["iterations"],
                "time_budget_min": self.time_budget, "initial_faces": c["initial_faces"],
                "max_levels": c["max_levels"], "level_iterations": c["level_iterations"], "init": c["init"] or "auto",
                "material": self.material}


def _one_at_a_time(base: str, variations: dict[str, list]) -> list[Setting]:
    out = []
    for knob, values in variations.items():
        for v in values:
            out.append(Setting(f"{base}:{knob}={v}", base, **{knob: v}))
    return out


GRIDS = {
    # two tiny settings for the CI smoke test (meant for the 'tiny' scene)
    "smoke": [Setting("smoke-a", "draft", max_size=24, spp=4, initial_faces=400, max_levels=1, iterations=8,
                      init="sphere"),
              Setting("smoke-b", "draft", max_size=32, spp=4, initial_faces=400, max_levels=2, iterations=90,
                      init="sphere")],
    # a first look: the Draft preset and two cheaper or richer neighbours
    "quick": [Setting("draft"), Setting("draft:max_size=64", max_size=64),
              Setting("draft:views_per_step=4", views_per_step=4)],
    # one knob at a time around Draft, plus the Balanced preset
    # (richer neighbours first, then cheaper ones: a sweep cut short still shows what buys accuracy)
    "full": [Setting("draft"), Setting("balanced", "balanced")] + _one_at_a_time("draft", {
        "max_size": [128], "initial_faces": [5000], "views_per_step": [4], "spp": [32], "max_levels": [4],
        "max_depth": [3]}) + _one_at_a_time("draft", {
        "max_size": [64], "spp": [8], "views_per_step": [1], "iterations": [150], "time_budget": [1.0],
        "initial_faces": [1000], "max_levels": [2]}),
    # the three presets as they ship (what `bench calibrate` measures)
    "presets": [Setting("draft"), Setting("balanced", "balanced"), Setting("final", "final")],
}


# -- measuring one run ------------------------------------------------------------------------------
def reconstruct_child(capture: Path, run: Path, setting: Setting, log: Path, seed: int = 0,
                      variant: str | None = None) -> dict:
    """Run ``python -m backend reconstruct`` for ``setting`` (its stderr to ``log``); wall and CPU
    seconds, peak memory, load average before and after, exit code."""
    argv = _launch.backend("reconstruct", capture, "--out", run, "--overwrite", "--seed", seed, *setting.args(),
                           *(["--variant", variant] if variant else []))
    child = _launch.run(argv, log=log, events=False)
    return {"seconds": child.seconds, "cpu_seconds": child.cpu_seconds, "peak_mb": child.peak_mb,
            "load_before": child.load_before, "load_after": child.load_after, "rc": child.rc}


# -- novel-view and relit scores ----------------------------------------------------------------
def result_display(run: Path):
    """The result with its material per vertex: the run's final display mesh when its last
    snapshot is the end of the run, else ``result.ply`` with the constants of ``report.json``'s
    ``material``."""
    run = Path(run)
    snap = run / "snapshot.json"
    if snap.is_file():
        info = json.loads(snap.read_text())
        path = run / info.get("mesh", "")
        if info.get("stage") == "done" and path.is_file():
            mesh = load_mesh(path)
            if mesh.vertex_colors is not None and {"specular", "roughness"} <= set(mesh.attributes or {}):
                return mesh
    material = json.loads((run / "report.json").read_text())["material"]
    result = load_mesh(run / "result.ply")
    mesh = Mesh(result.vertices, result.faces)
    n = mesh.n_vertices
    mesh.vertex_colors = np.tile(np.broadcast_to(np.asarray(material["albedo"], np.float32), 3), (n, 1))
    mesh.attributes = {k: np.full(n, float(np.ravel(material[k])[0]), np.float32) for k in ("specular", "roughness")}
    return mesh


def view_scores(run: Path, capture, spp: int = 128) -> dict:
    """PSNR/SSIM of the run's result, rendered with its material, at the capture's ground-truth
    held-out ("novel") and relit views, on the object's masks; path traced with as many
    vertices as the capture was. Empty when the capture has no such views."""
    mesh = result_display(run)
    prov = capture.provenance or {}
    max_depth = int(prov.get("spec", {}).get("max_depth") or prov.get("max_depth") or 4)
    out = {}
    for key, label in (("held_out", "novel"), ("relit", "relit")):
        rel = (capture.ground_truth or {}).get(key)
        if not rel:
            continue
        view_set = load_capture(capture.path(rel))
        rendered = render_views(mesh, view_set, spp, max_depth, seed=900)
        targets = [read_linear_rgb(f.image) for f in view_set.frames]
        masks = [read_mask(f.mask) if f.mask else None for f in view_set.frames]
        scores = image_metrics([rendered[f.name] for f in view_set.frames], targets,
                               None if any(m is None for m in masks) else masks)
        out[f"{label}_psnr"], out[f"{label}_ssim"] = scores["psnr"], scores["ssim"]
    return out


def scores(run: Path, capture_dir: Path, eval_spp: int = 64) -> dict:
    """One finished run's figures: geometry metrics and sizes from its report, novel-view and
    relit PSNR/SSIM of its result."""
    report = json.loads((run / "report.json").read_text())
    m = report.get("metrics") or {}
    out = dict(chamfer_l1=m.get("chamfer_l1"), f1=m.get("f1@0.01"), f1_005=m.get("f1@0.005"),
               loop_seconds=report["timings"]["total"], faces=report["result"]["faces"],
               iterations=report["result"]["iterations"], levels=len(report["levels"]),
               material=report.get("material"))
    out.update({k: round(v, 3) for k, v in view_scores(run, load_capture(capture_dir), eval_spp).items()})
    return out


# the figures a repeated setting reports as the median of its runs (the rest: its last run's)
MEDIAN_FIGURES = ("chamfer_l1", "f1", "f1_005", "loop_seconds", "iterations", "levels", "novel_psnr", "novel_ssim",
                  "relit_psnr", "relit_ssim")


def measure(scene: str, capture_dir: Path, setting: Setting, out: Path, repeats: int = 1,
            repeat_under: float = 0.0, variant: str | None = None, eval_spp: int = 64, seed: int = 0) -> dict:
    """Run one setting on one scene (repeated while cheap) and score its result. A repeated
    setting reports the median time and the median of each figure over its runs (each run is
    scored before the next overwrites its folder), with every run's time, F1 and held-out PSNR."""
    safe = setting.name.replace(":", "_").replace("=", "-")
    run = out / "runs" / scene / safe
    log = out / "logs" / scene / f"{safe}.log"
    runs, scored = [], []
    while True:
        runs.append(reconstruct_child(capture_dir, run, setting, log, seed, variant))
        if runs[-1]["rc"] != 0:
            break
        scored.append(scores(run, capture_dir, eval_spp))
        if len(runs) >= repeats or runs[0]["seconds"] >= repeat_under:
            break
    row = {"scene": scene, "name": setting.name, "setting": dataclasses.asdict(setting), "knobs": setting.knobs(),
           "args": setting.args(), "seed": seed, "repeats": len(runs), "rc": runs[-1]["rc"],
           "seconds_runs": [round(r["seconds"], 2) for r in runs],
           "seconds": round(statistics.median(r["seconds"] for r in runs), 2),
           "cpu_seconds": round(statistics.median(r["cpu_seconds"] for r in runs), 2),
           "peak_mb": round(max(r["peak_mb"] for r in runs), 1),
           "load_before": round(min(r["load_before"] for r in runs), 2),
           "load_after": round(max(r["load_after"] for r in runs), 2),
           "measured": time.strftime("%Y-%m-%dT%H:%M:%S"), "run": str(run)}
    if row["rc"] != 0:
        row["error"] = log.read_text()[-600:]
        return row
    row.update(median_scores(scored))
    if len(scored) > 1:
        row.update(f1_runs=[s["f1"] for s in scored], novel_psnr_runs=[s.get("novel_psnr") for s in scored])
    return row


def median_scores(scored: list[dict]) -> dict:
    """The last run's scores, each of ``MEDIAN_FIGURES`` replaced by its median over the runs
    that have it."""
    out = dict(scored[-1])
    for key in MEDIAN_FIGURES:
        values = [s[key] for s in scored if s.get(key) is not None]
        if values:
            if all(isinstance(v, int) for v in values):  # steps, levels, faces stay counts
                out[key] = statistics.median_low(values)
            else:
                out[key] = round(statistics.median(values), 6)
    return out


# -- results file ---------------------------------------------------------------------------------
def load_history(path: Path) -> list[dict]:
    """Every row of a results file (JSON lines), in the order measured."""
    if not Path(path).is_file():
        return []
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def load_results(path: Path) -> list[dict]:
    """Rows of a results file; a later row replaces an earlier one of the same scene and setting."""
    rows: dict[tuple, dict] = {}
    for row in load_history(path):
        rows[(row["scene"], row["name"])] = row
    return list(rows.values())


def append_result(path: Path, row: dict) -> None:
    """Append one row (the whole file is rewritten atomically)."""
    old = Path(path).read_text() if Path(path).is_file() else ""
    fsio.write_text(path, old + json.dumps(row) + "\n")


# -- command ---------------------------------------------------------------------------------------
def add_arguments(parser) -> None:
    parser.add_argument("--grid", choices=sorted(GRIDS), default="quick",
                        help="settings to run: smoke (two tiny ones), quick (Draft and two neighbours), "
                             "full (one knob at a time around Draft, plus Balanced), presets (default: %(default)s)")
    parser.add_argument("--scenes", default="dragon,blob_env,corner,armadillo_env,video",
                        help=f"comma-separated, of {', '.join(SCENES)} (default: %(default)s)")
    parser.add_argument("--settings", help="only the grid's settings with these names (comma-separated)")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "bench-sweep",
                        help="work folder: scenes, runs, logs, results.jsonl (default: %(default)s)")
    parser.add_argument("--report", type=Path, default=REPO / "bench",
                        help="where report.md, pareto_<scene>.png and results.json go (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per setting when cheap (default: %(default)s)")
    parser.add_argument("--repeat-under", type=float, default=30.0,
                        help="repeat only settings whose first run took fewer seconds (default: %(default)s)")
    parser.add_argument("--eval-spp", type=int, default=128,
                        help="samples per pixel of the scored renders (default: %(default)s)")
    parser.add_argument("--rerun", action="store_true", help="run settings already in results.jsonl again")
    parser.add_argument("--report-only", action="store_true", help="only rewrite the report from results.jsonl")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    parser.add_argument("--ray", nargs="?", const="local", metavar="ADDRESS",
                        help="run the grid as Ray tasks, one run per task: on the cluster at ADDRESS, or on a local "
                             "Ray instance when none is given (needs `pip install ray`; see bench/_ray.py)")
    parser.add_argument("--cpus-per-run", type=float, default=2,
                        help="with --ray: CPUs each run declares (Ray's num_cpus; default: %(default)s)")
    parser.add_argument("--all", action="store_true",
                        help="run every benchmark behind bench/records (and docs/results.md) into --out "
                             "(bench/_all.py): OUT/all.md holds each job's commands and tables")
    parser.add_argument("--only", help="with --all: only these jobs (comma-separated; --list names them)")
    parser.add_argument("--list", action="store_true", help="with --all: print the jobs and their hours, run nothing")


def run(args) -> int:
    emit = Emitter()
    if args.all or args.list:
        return _run_all(args, emit)
    ray = None
    if getattr(args, "ray", None) is not None:
        ray = require_ray()
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [s for s in scenes if s not in SCENES]
    if unknown:
        raise InputError(None, f"unknown scene {', '.join(unknown)}", f"choose from {', '.join(SCENES)}")
    grid = GRIDS[args.grid]
    if args.settings:
        wanted = {s.strip() for s in args.settings.split(",")}
        missing = wanted - {s.name for s in grid}
        if missing:
            raise InputError(None, f"grid '{args.grid}' has no setting {', '.join(sorted(missing))}",
                             f"choose from {', '.join(s.name for s in grid)}")
        grid = [s for s in grid if s.name in wanted]
    results = args.out / "results.jsonl"
    if not args.report_only:
        chosen = variant.choose(args.variant, emit)
        info = machine(chosen)
        code = code_version()
        done = {(r["scene"], r["name"]) for r in load_results(results) if r.get("rc") == 0}
        todo = [(scene, s) for scene in scenes for s in grid if args.rerun or (scene, s.name) not in done]

        def record(i, scene, setting, row):
            row["machine"], row["code"] = info, code
            append_result(results, row)
            emit("progress", stage="sweep", iteration=i, iterations=len(todo), fraction=i / len(todo),
                 scene=scene, setting=setting.name, seconds=row["seconds"], f1=row.get("f1"), rc=row["rc"])

        if ray is not None:
            todo_ray = [(scene, ensure(scene, args.out / "scenes", emit), s) for scene, s in todo]
            emit("stage", stage="sweep:ray", level=0, faces=0, runs=len(todo), cpus_per_run=args.cpus_per_run)
            run_tasks(ray, measure, todo_ray, args, record)
        for i, (scene, setting) in enumerate(todo if ray is None else []):
            capture = ensure(scene, args.out / "scenes", emit)
            emit("stage", stage=f"sweep:{scene}:{setting.name}", level=i, faces=0)
            row = measure(scene, capture, setting, args.out, args.repeats, args.repeat_under, args.variant,
                          args.eval_spp, args.seed)
            record(i + 1, scene, setting, row)
    rows = load_results(results)
    written = _report.write(rows, args.report, SCENES, history=load_history(results))
    good = _report.ok_rows(rows)
    _records.write_record(
        "sweep", title="Accuracy versus time: the sweep", variant=next((r["machine"].get("variant") for r in good
                                                                        if r.get("machine")), None),
        context=f"the benchmark scenes over the '{args.grid}' grid around Draft, one constant material, "
                "wall and CPU seconds of the whole reconstruct process; the full report is bench/report.md",
        rows=[{"scene": r["scene"], "setting": r["name"].replace("draft:", "draft, ").replace("=", " "),
               "wall s": round(r["seconds"]), "CPU s": round(r.get("cpu_seconds") or 0), "F1@0.01": round(r["f1"], 1),
               "Chamfer-L1": round(r["chamfer_l1"], 4), "held-out dB": _round(r.get("novel_psnr"), 1),
               "relit dB": _round(r.get("relit_psnr"), 1)}
              for r in sorted(good, key=lambda r: (list(SCENES).index(r["scene"]) if r["scene"] in SCENES else 99,
                                                   r["seconds"]))],
        plots=sorted({str(Path(args.report) / f"pareto_{r['scene']}.png") for r in good}))
    emit("done", report=str(written), results=str(results), runs=len(rows))
    return 0


def _round(value, digits: int):
    return None if value is None else round(value, digits)


def _run_all(args, emit) -> int:
    """``--all``: every job of bench/_all.py (``--list``: print them only)."""
    try:
        jobs = _all.select(args.only)
    except ValueError as err:
        raise InputError(None, str(err), "see python -m backend bench sweep --all --list") from None
    if args.list:
        print(_all.listing(jobs), flush=True)
        return 0
    records = _all.run_all(jobs, args.out, args.report, emit)
    emit("done", result=str(args.out / "all.md"), jobs=len(records), failed=[r["job"] for r in records if r["rc"]])
    return 0 if all(r["rc"] == 0 for r in records) else 1
