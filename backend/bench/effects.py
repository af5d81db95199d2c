"""Simulate only what a scene calls for: all effects on vs measured selection, per scene.

For each scene the same reconstruction runs with ``--effects all`` (every bounce, shadow
gradients, the specular lobe) and ``--effects auto`` (the measured selection), one after the
other at the same priority, and is scored: F1@0.01, albedo RMSE, held-out PSNR. The end of
the output is a table of every scene (wall-clock and CPU-time ratios, accuracy of both) with
the targets and whether each is met; ``OUT/results.json`` holds the same, written after
every run, so ``--reuse`` picks up finished runs (also from an earlier invocation).

Targets: the convex object under an HDR map at least 2x faster; the colour-
bleeding corner keeps multi-bounce light and its albedo RMSE matches the all-effects run;
no scene loses more than 1 F1 point or 0.5 dB held-out PSNR."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from .. import fsio, variant
from ..events import null_emitter
from ..metrics.evaluate import evaluate
from . import _records
from ._sweep_scenes import DRAGON, SCENES as BASE, Scene, _synth
from .sweep import REPO, Setting, code_version, machine, machine_line, reconstruct_child

SCENES = ("blob_env", "dragon_cornell", "corner")
REFERENCE, SELECTED = "all", "auto"
F1_POINTS, PSNR_DB = 1.0, 0.5  # the most accuracy the selection may lose against all effects
ALBEDO_MATCH = 0.01  # albedo RMSE this close to (or below) the all-effects run's "matches"
MIN_SPEEDUP = {"blob_env": 2.0}  # wall-clock targets per scene


@dataclass(frozen=True)
class EffectsRun(Setting):
    effects: str = "auto"
    material: str | None = None
    level_iterations: int | None = None


def _scene_builders():
    scenes = dict(BASE)
    scenes["dragon_cornell"] = Scene(
        "dragon_cornell", "the paper's dragon inside a Cornell-style room (the room is not modelled by the "
        "reconstruction: only the object's masked pixels are fitted), 24 views at 128 px, point lights",
        _synth(mesh=str(DRAGON), up="y", views=24, resolution=128, lighting="points", cornell=True,
               albedo=[0.6, 0.6, 0.6], specular=0.25, roughness=0.35, spp=256, max_depth=6, held_out=4))
    return scenes


def _ensure(name: str, root: Path, emit) -> Path:
    folder = root / name
    if not (folder / "capture.json").is_file():
        with fsio.atomic_dir(folder, replace=True) as tmp:
            _scene_builders()[name].build(tmp, emit)
    return folder


def _score(run: Path, capture: Path) -> dict:
    report = evaluate(run, capture, samples=50_000)
    own = json.loads((run / "report.json").read_text())
    decisions = own.get("effects", [])
    return {"f1": report["geometry"]["f1@0.01"], "chamfer_l1": report["geometry"]["chamfer_l1"],
            "albedo_rmse": report.get("albedo", {}).get("rmse"),
            "psnr": report.get("views", {}).get("held_out", {}).get("psnr"),
            "steps": own["result"]["iterations"], "levels": len(own["levels"]),
            "material_stages": [s["stage"] for s in own.get("material_schedule", {}).get("stages", [])],
            "decision": decisions[-1]["enabled"] if decisions else None,
            "decisions": [{"reason": d["reason"], "enabled": d["enabled"], "measured": d["measured"]}
                          for d in decisions]}


def describe(decision: dict | None) -> str:
    """'direct', '2 bounces', ... plus shadows / specular: what a run simulated (the panel's words)."""
    if not decision:
        return "-"
    depth = decision["max_depth"]
    parts = ["direct" if depth <= 2 else f"{depth - 1} bounces"]
    parts += [name for name in ("shadows", "specular") if decision.get(name)]
    return "+".join(parts)


def verdict(scene: str, reference: dict, selected: dict) -> list[dict]:
    """The targets for ``scene``: each {"target", "value", "ok"} (the selection
    against the all-effects run)."""
    checks = []
    speedup = reference["seconds"] / max(selected["seconds"], 1e-9)
    if scene in MIN_SPEEDUP:
        checks.append({"target": f">= {MIN_SPEEDUP[scene]:g}x faster", "value": f"{speedup:.2f}x",
                       "ok": speedup >= MIN_SPEEDUP[scene]})
    if scene == "corner":
        depth = (selected.get("decision") or {}).get("max_depth", 2)
        checks.append({"target": "keeps multi-bounce", "value": f"depth {depth}", "ok": depth >= 3})
        a, s = reference.get("albedo_rmse"), selected.get("albedo_rmse")
        checks.append({"target": f"albedo RMSE matches (+{ALBEDO_MATCH:g})",
                       "value": "-" if None in (a, s) else f"{s - a:+.3f}",
                       "ok": a is not None and s is not None and s <= a + ALBEDO_MATCH})
    df1 = selected["f1"] - reference["f1"]
    checks.append({"target": f"F1 within {F1_POINTS:g}", "value": f"{df1:+.2f}", "ok": df1 >= -F1_POINTS})
    a, s = reference.get("psnr"), selected.get("psnr")
    checks.append({"target": f"PSNR within {PSNR_DB:g} dB", "value": "-" if None in (a, s) else f"{s - a:+.2f}",
                   "ok": a is not None and s is not None and s - a >= -PSNR_DB})
    return checks


def summarise(scene: str, rows: dict[str, dict]) -> dict | None:
    """Ratios and target checks of one scene's runs (None until both ran)."""
    ref, sel = rows.get(REFERENCE), rows.get(SELECTED)
    if not ref or not sel or ref.get("rc") != 0 or sel.get("rc") != 0:
        return None
    checks = verdict(scene, ref, sel)
    return {"speedup": ref["seconds"] / max(sel["seconds"], 1e-9),
            "cpu_speedup": ref["cpu_seconds"] / max(sel["cpu_seconds"], 1e-9),
            "checks": checks, "ok": all(c["ok"] for c in checks)}


def table(results: dict) -> str:
    """The compact all-scenes table with the targets and pass/fail."""
    def pair(a: dict, b: dict, key: str, spec: str) -> str:
        return "/".join("-" if r.get(key) is None else format(r[key], spec) for r in (a, b))

    lines = [f"{'scene':<15}{'steps':>8}{'all s':>8}{'auto s':>8}{'wall':>7}{'cpu':>7}  {'F1 all/auto':<13}"
             f"{'albedo':<13}{'PSNR':<13}{'selected':<22}targets"]
    for scene, runs in results["scenes"].items():
        ref, sel, summary = runs.get(REFERENCE, {}), runs.get(SELECTED, {}), results["summary"].get(scene)
        if summary is None:
            lines.append(f"{scene:<15} incomplete: " + ", ".join(f"{m} rc={r.get('rc')}" for m, r in runs.items()))
            continue
        steps = f"{ref.get('steps')}/{sel.get('steps')}"
        checks = "; ".join(f"{c['target']} {c['value']} {'ok' if c['ok'] else 'FAIL'}" for c in summary["checks"])
        lines.append(f"{scene:<15}{steps:>8}{ref['seconds']:>8.0f}{sel['seconds']:>8.0f}"
                     f"{summary['speedup']:>6.1f}x{summary['cpu_speedup']:>6.1f}x  "
                     f"{pair(ref, sel, 'f1', '.2f'):<13}{pair(ref, sel, 'albedo_rmse', '.3f'):<13}"
                     f"{pair(ref, sel, 'psnr', '.2f'):<13}{describe(sel.get('decision')):<22}"
                     f"{'PASS' if summary['ok'] else 'FAIL'}: {checks}")
        for mode, row in runs.items():
            if mode in (REFERENCE, SELECTED) or row.get("rc") != 0:
                continue
            lines.append(f"{'  ' + mode:<15}{row.get('steps')!s:>8}{'':>8}{row['seconds']:>8.0f}"
                         f"{ref['seconds'] / max(row['seconds'], 1e-9):>6.1f}x"
                         f"{ref['cpu_seconds'] / max(row['cpu_seconds'], 1e-9):>6.1f}x  "
                         f"{pair(ref, row, 'f1', '.2f'):<13}{pair(ref, row, 'albedo_rmse', '.3f'):<13}"
                         f"{pair(ref, row, 'psnr', '.2f'):<13}{describe(row.get('decision')):<22}(extra mode)")
    lines.append(f"wall/cpu: all-effects seconds over selected (wall clock; CPU time of the run). Targets: "
                 f"F1 within {F1_POINTS:g} point, PSNR within {PSNR_DB:g} dB of all effects; blob_env "
                 f">= {MIN_SPEEDUP['blob_env']:g}x; corner keeps multi-bounce, albedo RMSE within {ALBEDO_MATCH:g}.")
    return "\n".join(lines)


def add_arguments(parser) -> None:
    parser.add_argument("--scenes", default=",".join(SCENES), help="comma-separated (default: %(default)s)")
    parser.add_argument("--preset", default="draft", help="reconstruct preset for both runs (default: %(default)s)")
    parser.add_argument("--iterations", type=int, default=150,
                        help="cap on optimisation steps of each run, 0 for none (then the preset's levels run "
                             "to their plateaus and the material schedule to its end) (default: %(default)s)")
    parser.add_argument("--max-levels", type=int, help="reconstruct --max-levels (default: the preset's)")
    parser.add_argument("--level-iterations", type=int, help="reconstruct --level-iterations (default: the preset's)")
    parser.add_argument("--material", default="staged", help="reconstruct --material (default: %(default)s)")
    parser.add_argument("--modes", default=f"{REFERENCE};{SELECTED}",
                        help="';'-separated --effects values to run per scene; 'all' and 'auto' are compared "
                             "against the targets, others are listed against 'all' (e.g. 'all;auto;auto,-shadows') "
                             "(default: %(default)s)")
    parser.add_argument("--reuse", action="store_true",
                        help="keep runs already in OUT/results.json with the same options instead of running again")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "bench-effects", help="work folder")


def run(args) -> int:
    variant.choose()  # scenes are synthesised (and runs scored) in this process
    emit = null_emitter()
    path = args.out / "results.json"
    previous = json.loads(path.read_text()) if args.reuse and path.is_file() else {}
    previous = previous if isinstance(previous, dict) else {}  # an older bench's list of rows
    # runs of other scenes from an earlier invocation stay in the table
    results = {"machine": machine(), "code": code_version(), "scenes": json.loads(json.dumps(previous.get("scenes", {}))), "summary": {}}
    for scene, runs in results["scenes"].items():
        results["summary"][scene] = summarise(scene, runs)
    print(machine_line(results["machine"]), f"load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"{'scene':<15} {'effects':<14} {'seconds':>8} {'cpu s':>7} {'load':>5} {'F1@1%':>7} {'albedo':>7} "
          f"{'PSNR':>6}  selected", flush=True)
    modes = [m.strip() for m in args.modes.split(";") if m.strip()]
    for scene in [s for s in args.scenes.split(",") if s]:
        capture = _ensure(scene, args.out / "scenes", emit)
        runs = results["scenes"][scene] = {}
        for mode in modes:
            setting = EffectsRun(name=f"{scene}-{mode}", preset=args.preset, iterations=args.iterations or None,
                                 max_levels=args.max_levels, level_iterations=args.level_iterations,
                                 effects=mode, material=args.material)
            run_dir = args.out / "runs" / scene / mode.replace(",", "_")
            old = previous.get("scenes", {}).get(scene, {}).get(mode)
            if old and old.get("args") == setting.args() and old.get("rc") == 0 and (run_dir / "report.json").is_file():
                row = {**old, "reused": True}
            else:
                timing = reconstruct_child(capture, run_dir, setting,
                                           args.out / "logs" / f"{scene}-{mode.replace(',', '_')}.log")
                row = {"scene": scene, "effects": mode, "args": setting.args(), "code": results["code"],
                       "seconds": round(timing["seconds"], 1), "cpu_seconds": round(timing["cpu_seconds"], 1),
                       "load": [round(timing["load_before"], 1), round(timing["load_after"], 1)], "rc": timing["rc"]}
                if timing["rc"] == 0:
                    row.update(_score(run_dir, capture))
            runs[mode] = row
            fmt = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
            print(f"{scene:<15} {mode:<14} {row['seconds']:>8.1f} {row['cpu_seconds']:>7.1f} {row['load'][1]:>5.1f} "
                  f"{fmt(row.get('f1'), '7.2f')} {fmt(row.get('albedo_rmse'), '7.3f')} {fmt(row.get('psnr'), '6.2f')}"
                  f"  {describe(row.get('decision'))}{' (reused)' if row.get('reused') else ''}", flush=True)
            results["summary"][scene] = summarise(scene, runs)
            fsio.write_json(path, results)
    print(flush=True)
    print(table(results), flush=True)
    _records.write_record(
        "effects", title="Effects: simulate only what a scene calls for", merge_on="scene",
        context=f"each scene run with every effect on (all) and with the measured selection (auto), {args.preset.capitalize()}"
                + (f", steps capped at {args.iterations}" if args.iterations else ", uncapped"),
        rows=record_rows(results))
    return 0


def record_rows(results: dict) -> list[dict]:
    """One row per scene whose two runs finished: times, ratio, accuracy of both, the selection."""
    rows = []
    for scene, runs in results["scenes"].items():
        ref, sel, summary = runs.get(REFERENCE, {}), runs.get(SELECTED, {}), results["summary"].get(scene)
        if summary is None:
            continue

        def pair(key, spec):
            return " / ".join("-" if r.get(key) is None else format(r[key], spec) for r in (ref, sel))

        rows.append({"scene": scene, "all s": round(ref["seconds"], 1), "auto s": round(sel["seconds"], 1),
                     "wall / CPU ratio": f"{summary['speedup']:.2f}x / {summary['cpu_speedup']:.2f}x",
                     "F1 all / auto": pair("f1", ".2f"), "albedo RMSE all / auto": pair("albedo_rmse", ".3f"),
                     "PSNR all / auto": pair("psnr", ".2f"), "selected": describe(sel.get("decision")),
                     "targets": "pass" if summary["ok"] else "FAIL: " + ", ".join(
                         c["target"] for c in summary["checks"] if not c["ok"])})
    return rows
