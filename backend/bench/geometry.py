"""Geometry reconstruction: the paper-style dragon, shape from shading, genus change, memory.

Parts (``--only``, comma separated):

- ``dragon``: the Shape-from-Tracing dragon synthesised with 32 views at 128 px under the
  paper's point lights (glossy grey material), reconstructed from space carving within the
  time budget; prints the time-vs-F1 curve. Goals: F1@0.01 >= 90 and Chamfer-L1 below half
  the initial mesh's, within 10 minutes.
- ``colmap``: the same capture, starting from the authors' COLMAP mesh (same frame).
- ``divot``: a sphere with a dent no silhouette shows, 5 cameras x 4 light positions,
  starting from the sphere; goal: the dent's depth within 20 %.
- ``genus``: a torus (genus 1) reconstructed from a sphere (genus 0); goal: genus 1.
- ``memory``: optimisation steps on a 200k-face mesh at 128 px; goal: under 8 GB resident.

Captures are cached in ``--out``; runs are repeated. Timings depend on the machine's load."""

from __future__ import annotations

import json
import time
from pathlib import Path

from .. import variant
from ..errors import InputError
from ..geometry.mesh import load_mesh, save_mesh
from ..geometry.topology import genus
from ..synth.capture import Y_UP_TO_Z_UP
from . import _launch, _records
from ._data import SHARED_DATA
from ._scenes import divot_capture, divot_depth, torus

PARTS = ("dragon", "colmap", "divot", "genus", "memory")
DRAGON = SHARED_DATA / "meshes" / "shapefromtracing"
DRAGON_MATERIAL = ("0.6,0.6,0.6", 0.3, 0.3)


def add_arguments(parser):
    parser.add_argument("--only", default=",".join(PARTS), help=f"parts to run ({','.join(PARTS)})")
    parser.add_argument("--out", type=Path, default=Path("bench_geometry"), help="folder for captures and runs")
    parser.add_argument("--minutes", type=float, default=10.0, help="time budget of each dragon run")
    parser.add_argument("--material", default="auto",
                        help="material given to the dragon runs: auto (estimated) or known (the synthetic one)")
    parser.add_argument("--effects", default="auto",
                        help="light-transport effects for the dragon runs (default: auto, what reconstruct does; "
                             "'specular' is direct light only)")
    parser.add_argument("--data", type=Path, default=DRAGON, help="folder with dragon.obj and colmap_dragon.obj")


def _backend(*args) -> _launch.Child:
    """``python -m backend ARGS``; raises with the child's last error line."""
    return _launch.run(_launch.backend(*args), what=f"backend {args[0]}")


def _report(run: Path) -> dict:
    return json.loads((run / "report.json").read_text())


def _print_curve(report: dict) -> None:
    init = report["init"]["metrics"]
    print(f"    {'seconds':>8} {'level':>5} {'faces':>6} {'F1@0.01':>8} {'Chamfer':>8}   (100k samples each)")
    print(f"    {report['init']['seconds']:8.1f} {'init':>5} {report['init']['faces']:6d} "
          f"{init['f1@0.01']:8.2f} {init['chamfer_l1']:8.5f}")
    for lv in report["levels"]:
        m = lv.get("metrics") or {}
        if m:
            print(f"    {lv['elapsed']:8.1f} {lv['level']:5d} {lv['faces']:6d} {m['f1@0.01']:8.2f} {m['chamfer_l1']:8.5f}")
    fin = report["metrics"]
    print(f"    {report['timings']['total']:8.1f} {'final':>5} {report['result']['faces']:6d} "
          f"{fin['f1@0.01']:8.2f} {fin['chamfer_l1']:8.5f}")


def dragon_capture(out: Path, data: Path) -> Path:
    capture = out / "dragon_capture"
    if not (capture / "capture.json").is_file():
        albedo, spec, rough = DRAGON_MATERIAL
        _backend("synth", "--out", capture, "--mesh", data / "dragon.obj", "--up", "y", "--views", 32,
                 "--resolution", 128, "--lighting", "points", "--albedo", albedo, "--specular", spec,
                 "--roughness", rough, "--held-out", 0, "--overwrite")
    return capture


def _material(spec: str) -> str:
    if spec == "known":
        albedo, s, r = DRAGON_MATERIAL
        return f"known:{albedo}:{s}:{r}"
    return spec


def run_dragon(args, init: str, name: str) -> dict:
    capture = dragon_capture(args.out, args.data)
    if init == "colmap":
        path = args.out / "colmap_dragon_zup.ply"
        save_mesh(path, load_mesh(args.data / "colmap_dragon.obj").transformed(Y_UP_TO_Z_UP))
        init = str(path)
    run = args.out / f"run_{name}"
    start = time.perf_counter()
    _backend("reconstruct", capture, "--out", run, "--overwrite", "--init", init, "--preset", "balanced",
             "--max-size", 128, "--coarse-size", 128, "--time-budget", args.minutes,
             "--material", _material(args.material), "--effects", args.effects, "--track-metrics")
    wall = time.perf_counter() - start
    report = _report(run)
    init_m, fin = report["init"]["metrics"], report["metrics"]
    print(f"  {name}: {init} -> F1@0.01 {init_m['f1@0.01']:.2f} -> {fin['f1@0.01']:.2f}, "
          f"Chamfer-L1 {init_m['chamfer_l1']:.5f} -> {fin['chamfer_l1']:.5f} "
          f"({fin['chamfer_l1'] / init_m['chamfer_l1']:.2f} of the initial), {wall / 60:.1f} min wall")
    _print_curve(report)
    goals = {"f1>=90": fin["f1@0.01"] >= 90.0, "chamfer<=half": fin["chamfer_l1"] <= 0.5 * init_m["chamfer_l1"],
             "within_10_min": report["timings"]["total"] <= 600.0 + 5.0}  # the run's clock; startup aside
    print(f"  goals: {goals}")
    return {"init": init_m, "final": fin, "wall_s": wall, "levels": report["levels"], "goals": goals}


def run_divot(args) -> dict:
    variant.choose()  # the divot capture is rendered here, with Mitsuba
    depth, width = 0.15, 0.35
    capture = args.out / "divot_capture"
    if not (capture / "capture.json").is_file():
        divot_capture(capture, depth, width)
    run = args.out / "run_divot"
    start = time.perf_counter()
    _backend("reconstruct", capture, "--out", run, "--overwrite", "--init", "sphere", "--max-size", 128,
             "--material", "known:0.6,0.6,0.6:0.1:0.5", "--max-levels", 2, "--effects", args.effects)
    wall = time.perf_counter() - start
    found = divot_depth(load_mesh(run / "result.ply"), width)
    error = abs(found - depth) / depth
    print(f"  divot: true depth {depth:.4f}, recovered {found:.4f} (error {100 * error:.1f} %, goal <= 20 %), "
          f"{wall:.0f} s")
    return {"depth": depth, "recovered": found, "error": error, "wall_s": wall, "goal": error <= 0.2}


def run_genus(args) -> dict:
    capture = args.out / "torus_capture"
    if not (capture / "capture.json").is_file():
        save_mesh(args.out / "torus.ply", torus())
        _backend("synth", "--out", capture, "--mesh", args.out / "torus.ply", "--views", 16, "--resolution", 48,
                 "--albedo", "0.6,0.6,0.6", "--held-out", 0, "--overwrite")
    run = args.out / "run_genus"
    start = time.perf_counter()
    _backend("reconstruct", capture, "--out", run, "--overwrite", "--init", "sphere", "--max-size", 48,
             "--coarse-size", 48, "--initial-faces", 1000, "--material", "known:0.6,0.6,0.6:0.25:0.35",
             "--max-levels", 3, "--step", 0.3, "--effects", args.effects)
    report = _report(run)
    result = genus(load_mesh(run / "result.ply"))
    print(f"  genus: start {report['init']['genus']}, target 1, result {result}; "
          f"F1@0.01 {report['metrics']['f1@0.01']:.1f}; {time.perf_counter() - start:.0f} s")
    return {"start": report["init"]["genus"], "result": result, "goal": result == 1}


MEMORY_PROBE = """
import json, resource, sys, time
import numpy as np
from backend import variant
variant.choose()
from backend.capture import load_capture
from backend.geometry.init.carve import carve
from backend.geometry.simplify import simplify
from backend.geometry.subdivide import midpoint
from backend.material.constant import ConstantMaterial
from backend.optimize.objective import Objective
from backend.optimize.steps import VertexOptimizer
from backend.optimize.views import ViewSet
from backend.render.scene import RenderSettings
capture = load_capture(sys.argv[1])
mesh = carve(capture, 60000)
while mesh.n_faces < 200000:
    mesh = midpoint(mesh)[0]
mesh = simplify(mesh, 200000)
views = ViewSet(capture, 128).at(128)
objective = Objective(mesh, ConstantMaterial(), views, RenderSettings(spp=16, sppc=16, sppp=4, sppi=0,
                      integrator="direct_projective"))
opt = VertexOptimizer(mesh.vertices, mesh.faces, 20.0, 1e-4)
v, start = mesh.vertices, time.perf_counter()
for step in range(int(sys.argv[2])):
    loss, grad, _ = objective.loss_and_grad(v, [step % len(views), (step + 7) % len(views)], 100 + step)
    v = opt.step(grad)
seconds = (time.perf_counter() - start) / int(sys.argv[2])
print(json.dumps({"faces": mesh.n_faces, "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
                  "seconds_per_step": seconds}))
"""


def run_memory(args) -> dict:
    capture = dragon_capture(args.out, args.data)
    proc = _launch.run(_launch.python("-c", MEMORY_PROBE, capture, 10), what="memory probe")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["goal"] = out["peak_rss_gb"] < 8.0
    print(f"  memory: {out['faces']} faces at 128 px, 2 views per step: peak resident {out['peak_rss_gb']:.2f} GB "
          f"(goal < 8), {out['seconds_per_step']:.2f} s per step")
    return out


def record_rows(results: dict, minutes: float) -> list[dict]:
    """One row per part: what it ran, its result and its goal."""
    rows = []
    for part, label in (("dragon", "dragon from carving"), ("colmap", "dragon from the authors' COLMAP mesh")):
        r = results.get(part)
        if r:
            ratio = r["final"]["chamfer_l1"] / r["init"]["chamfer_l1"]
            rows.append({"part": label, "result": f"F1@0.01 {r['init']['f1@0.01']:.1f} → {r['final']['f1@0.01']:.1f}, "
                                                  f"Chamfer {ratio:.2f}x the initial, {r['wall_s'] / 60:.1f} min",
                         "goal": f"F1 ≥ 90, Chamfer ≤ 0.5x, ≤ {minutes:g} min"})
    if "divot" in results:
        r = results["divot"]
        rows.append({"part": "shape from shading (a dent no silhouette shows)",
                     "result": f"depth {r['recovered']:.4f} of {r['depth']:g} ({100 * r['error']:.1f} % error), "
                               f"{r['wall_s']:.0f} s", "goal": "within 20 %"})
    if "genus" in results:
        r = results["genus"]
        rows.append({"part": "genus change (torus from a sphere)", "result": f"genus {r['start']} → {r['result']}",
                     "goal": "genus 1"})
    if "memory" in results:
        r = results["memory"]
        rows.append({"part": f"memory, {r['faces']} faces at 128 px",
                     "result": f"peak {r['peak_rss_gb']:.2f} GB, {r['seconds_per_step']:.2f} s per step",
                     "goal": "< 8 GB"})
    return rows


def run(args) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    parts = [p.strip() for p in args.only.split(",") if p.strip()]
    unknown = set(parts) - set(PARTS)
    if unknown:
        raise InputError(None, f"unknown part(s) {', '.join(sorted(unknown))}", f"choose from {', '.join(PARTS)}")
    if {"dragon", "colmap", "memory"} & set(parts) and not (args.data / "dragon.obj").is_file():
        raise InputError(args.data / "dragon.obj", "dragon mesh not found", "pass --data with the shared meshes")
    results = {}
    for part in parts:
        print(f"[{part}]", flush=True)
        if part == "dragon":
            results[part] = run_dragon(args, "carve", "dragon_carve")
        elif part == "colmap":
            results[part] = run_dragon(args, "colmap", "dragon_colmap")
        elif part == "divot":
            results[part] = run_divot(args)
        elif part == "genus":
            results[part] = run_genus(args)
        elif part == "memory":
            results[part] = run_memory(args)
    (args.out / "bench_geometry.json").write_text(json.dumps(results, indent=2, default=float))
    _records.write_record("geometry", title="Geometry",
                          context="the geometry targets: the dragon from carving and from the authors' COLMAP mesh, "
                                  "shape from shading, a change of genus, memory at 200k faces",
                          rows=record_rows(results, args.minutes), merge_on="part")
    print(f"results: {args.out / 'bench_geometry.json'}")
    return 0
