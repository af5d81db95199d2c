"""Calibrate the quality presets on this machine: time and accuracy of Draft/Balanced/Final
on one calibration scene per kind of lighting.

``python -m backend bench calibrate [--presets draft,balanced,final] [--scenes dragon,armadillo_env]
[--material staged|constant] [--out FILE]`` runs each preset on each scene (synthesised once;
see ``bench sweep``) exactly as ``reconstruct --preset NAME`` would, with reconstruct's
default material (``MATERIAL``, staged mesh colors: the run the panel's Reconstruct button
starts, so the times the panel promises are that run's), and writes the calibration file
(default ``backend/presets.json``, which the Blender panel reads)::

    {"machine": "CPU, N cores, variant", "machine_details": {...}, "measured": ..., "scene": ...,
     "code": COMMIT, "presets": {"draft": {"expected_minutes": ..., "expected_f1": ..., ...}, ...},
     "kinds": {"point": {"scene": ..., "presets": {...}}, "environment": {...}}}

The top level is the dragon's (point lights); ``kinds`` holds every kind's, ``environment``
from the armadillo under an HDR map, which shades itself (the HDR-lit case where more levels
pay), which a capture lit by an environment map is promised and its time budget read against
(planning/presets.py, ``calibrated``). A kind that ``--scenes`` leaves out keeps its entries
from the file being replaced, and so does a preset that ``--presets`` leaves out; every entry
names its ``material``, ``code`` (the commit it ran) and ``machine`` (entries measured on
different machines share the file; the top-level ``machine`` is the latest call's), and each
kind its entries' materials.
``--material constant`` calibrates the one constant material instead (a row per preset of its
own in the work folder's results; its file defaults to ``WORK/presets-constant.json`` and its
record to ``calibrate-constant``, so the shipped file stays the default material's).
``expected_f1`` is F1@0.01 as a fraction (0.9 = 90 %).
``--from-results FILE`` writes the file from a sweep's ``results.jsonl`` instead of running
anything; then each preset also gets
``recommended_overrides`` (ReconstructConfig fields, as in ``planning/presets.py``): the
settings of the most accurate swept run that fits the preset's time target, when it beats the
preset by more than ``--margin`` F1 points. Each entry records the preset's ``overrides`` as
they were measured and ``code`` the commit; the ``done`` event lists presets another one
dominates (as fast or faster and as accurate or more), and the file marks each with
``dominated_by``: the point-lit kind must have none; in another kind a marked preset buys
nothing there, so a time budget never picks it and the panel says so.
``backend.planning.presets.preset_for_budget`` picks a preset for a time budget from the file."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

from .. import fsio, variant
from ..errors import InputError, require
from ..events import Emitter
from ..planning.presets import CALIBRATION_FILE, PRESETS
from ._machine import code_version, machine, machine_line
from ._sweep_scenes import SCENES, ensure
from . import _records
from .sweep import GRIDS, append_result, load_history, measure

REPO = Path(__file__).resolve().parents[2]
SCENE = "dragon"
# the calibration scene of each kind of lighting (planning/presets.py: lighting_kind); the
# dragon's figures are also the file's top-level ones, for readers older than kinds
# (not the textured blob under a map: Draft saturates F1@0.01 there, so every costlier preset
# is dominated; docs/notes/2026-11-29-hdr-calibration.md)
KINDS = {"point": "dragon", "environment": "armadillo_env"}
# the material the presets are calibrated with: reconstruct's default (planning/job.py
# DEFAULT_MATERIAL, the staged mesh colors); --material constant calibrates one constant
# material into a file of its own
MATERIAL = "staged"
MATERIAL_CHOICES = ("staged", "constant")
# time (minutes) and F1@0.01 (percent) each preset is meant to reach on the dragon; None: no limit
TARGETS = {"draft": (3.0, 80.0), "balanced": (10.0, 90.0), "final": (None, None)}


def row_material(row: dict) -> str:
    """The material a sweep row's run fitted (a row that does not say is the sweep's one
    constant material)."""
    return (row.get("knobs") or {}).get("material") or "constant"


def entry_material(entry: dict) -> str:
    """The material a calibration entry was measured with (an entry written before entries
    named it: its settings', else constant)."""
    return entry.get("material") or (entry.get("settings") or {}).get("material") or "constant"


def entry_machine(entry: dict, doc: dict | None = None) -> str | None:
    """The machine a calibration entry was measured on: its own ``machine``, else (an entry
    written before entries named it) that of ``doc``, the calibration it was read from."""
    return entry.get("machine") or (doc or {}).get("machine")


def calibration_rows(path: Path) -> list[dict]:
    """The rows of a results file, a later row replacing an earlier one of the same scene,
    setting and material (a preset calibrated with both materials keeps a row of each)."""
    rows: dict[tuple, dict] = {}
    for row in load_history(path):
        rows[(row["scene"], row["name"], row_material(row))] = row
    return list(rows.values())


def entry(row: dict) -> dict:
    """A preset's calibration entry from a sweep row."""
    out = {"expected_minutes": round(row["seconds"] / 60, 2), "expected_f1": round(row["f1"] / 100, 4),
           "material": row_material(row),
           "cpu_minutes": round(row["cpu_seconds"] / 60, 2), "chamfer_l1": row.get("chamfer_l1"),
           "f1_005": None if row.get("f1_005") is None else round(row["f1_005"] / 100, 4),
           "novel_psnr": row.get("novel_psnr"), "relit_psnr": row.get("relit_psnr"),
           "peak_memory_mb": row.get("peak_mb"), "load_average": [row.get("load_before"), row.get("load_after")],
           "runs": row.get("repeats", 1), "settings": row["knobs"], "code": row.get("code"),
           # entries measured on different machines share one file
           "machine": machine_line(row["machine"]) if isinstance(row.get("machine"), dict) else row.get("machine"),
           # the run's levels and steps: planning/time_plan.py predicts other captures' times from them
           "iterations": row.get("iterations"), "levels": row.get("levels"), "faces": row.get("faces")}
    return out


def _target(name: str, row: dict) -> dict | None:
    minutes, f1 = TARGETS.get(name, (None, None))
    if minutes is None:
        return None
    return {"minutes": minutes, "f1": f1 / 100, "met": bool(row["seconds"] / 60 <= minutes and row["f1"] >= f1)}


def overrides(preset_knobs: dict, knobs: dict) -> dict:
    """The ReconstructConfig fields (as in planning/presets.py) that turn a preset's
    knobs into ``knobs``."""
    out = {}
    for k, v in knobs.items():
        if preset_knobs.get(k) == v:
            continue
        if k == "bounces":
            out.update({"integrator": "direct_projective"} if v == 1 else {"integrator": "prb_projective",
                                                                           "max_depth": v + 1})
        elif k == "time_budget_min":
            out["time_budget_s"] = None if v is None else 60.0 * v
        elif k == "init":
            out["init"] = None if v == "auto" else v
        else:
            out[k] = v
    return out


def recommend(name: str, preset_row: dict, rows: list[dict], margin: float) -> dict:
    """The most accurate row of ``rows`` within the preset's time target (or its own time, for
    a preset without a target), when it beats the preset by more than ``margin`` F1 points."""
    minutes = TARGETS.get(name, (None, None))[0]
    limit = 60 * minutes if minutes is not None else preset_row["seconds"]
    fitting = [r for r in rows if r["seconds"] <= limit and r["name"] != name]
    if not fitting:
        return {}
    best = max(fitting, key=lambda r: r["f1"])
    if best["f1"] <= preset_row["f1"] + margin:
        return {}
    return {"recommended_overrides": overrides(preset_row["knobs"], best["knobs"]),
            "recommended_from": best["name"], "recommended_expected_minutes": round(best["seconds"] / 60, 2),
            "recommended_expected_f1": round(best["f1"] / 100, 4)}


def dominated(presets: dict) -> list[tuple[str, str]]:
    """(preset, by) for every calibrated preset that another is at least as fast and at least as
    accurate as (F1@0.01)."""
    out = []
    for name, p in presets.items():
        for other, q in presets.items():
            if other != name and q["expected_minutes"] <= p["expected_minutes"] and q["expected_f1"] >= p["expected_f1"]:
                out.append((name, other))
                break
    return out


def _keep(new: dict, old: dict | None) -> dict:
    """``new`` (a kind's calibration from this call's rows) with the presets it did not run
    taken from ``old`` (the same kind in the file being replaced), so one preset can be
    measured again alone; the commits and date then cover both."""
    kept = {n: {**e, "machine": entry_machine(e, old)} for n, e in ((old or {}).get("presets") or {}).items()
            if n not in new["presets"]}
    if not kept:
        return new
    # a kept entry names its own commit; one written before entries did stands for the old file's
    sources = [new.get("code")] + [e.get("code") or old.get("code") for e in kept.values()]
    codes = {c.strip() for code in sources for c in str(code or "").split(",") if c.strip()}
    merged = {n: new["presets"].get(n) or kept[n] for n in TARGETS if n in new["presets"] or n in kept}
    return {**new, "presets": merged, "material": materials_of(merged),
            "code": ", ".join(sorted(codes)), "measured": max(new["measured"], old.get("measured") or "")}


def materials_of(presets: dict) -> str:
    """The materials a kind's entries were measured with, e.g. 'staged' or 'constant, staged'
    (a file part recalibrated with another material than the rest)."""
    return ", ".join(sorted({entry_material(e) for e in presets.values()}))


def flag_dominated(doc: dict) -> dict:
    """``doc`` (a kind's calibration) with ``dominated_by`` on each preset that a cheaper one
    dominates, naming that one: a time budget never picks it and the panel says it buys
    nothing there. The point-lit kind must have none (tests/bench/test_presets_calibration.py)."""
    presets = {n: {k: v for k, v in e.items() if k != "dominated_by"} for n, e in doc["presets"].items()}
    for name, by in dominated(presets):
        presets[name]["dominated_by"] = by
    return {**doc, "presets": presets}


def calibration(rows: list[dict], machine: dict, margin: float = 1.0, previous: dict | None = None,
                material: str = MATERIAL) -> dict:
    """The calibration document from sweep rows of the calibration scenes (presets named as in
    PRESETS) fitted with ``material`` (rows of another material are left out): the dragon's
    entries at the top level, every kind's under ``kinds``. A kind without rows keeps its
    entries from ``previous`` (the file being replaced), and a kind with rows keeps the
    presets they leave out, so one kind, or one preset, can be calibrated at a time."""
    previous = previous or {}
    old = previous.get("kinds") or ({"point": previous} if isinstance(previous.get("presets"), dict) else {})
    kinds = {}
    for kind, scene in KINDS.items():
        doc = scene_calibration([r for r in rows if r.get("scene", SCENE) == scene and row_material(r) == material],
                                machine, scene, margin)
        if doc["presets"]:
            kinds[kind] = flag_dominated(_keep(doc, old.get(kind)))
    if "point" not in kinds and "point" in old:  # the top level is the point-lit kind's, as written then
        top = {k: v for k, v in previous.items() if k != "kinds"}
    else:
        top = kinds.get("point") or scene_calibration([], machine, SCENE, margin)
    sources = {**{k: d for k, d in old.items() if k in KINDS}, **kinds}  # this call's rows win
    return {**top, "kinds": {k: {**{key: sources[k].get(key) for key in ("scene", "measured", "code", "presets")},
                                 "material": materials_of(sources[k].get("presets") or {})}
                             for k in KINDS if k in sources}}


def previous_calibration(path: Path) -> dict | None:
    """The calibration file at ``path`` (None when there is none), whose kinds a call that
    does not run them keeps."""
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(path, f"not a readable calibration file ({exc})",
                         "delete it, or write to another file with --out") from None
    require(isinstance(doc, dict) and isinstance(doc.get("kinds", {}), dict), path, "not a calibration file",
            "delete it, or write to another file with --out")
    return doc


def scene_calibration(rows: list[dict], machine: dict, scene: str, margin: float = 1.0) -> dict:
    """The calibration entries of one scene's rows."""
    good = [r for r in rows if r.get("rc") == 0 and r.get("f1") is not None]
    presets = {}
    for name in TARGETS:
        row = next((r for r in good if r["name"] == name), None)
        if row is None:
            continue
        presets[name] = entry(row)
        # the preset as it was when its run was measured (None: not recorded): a test compares
        # it with planning/presets.py
        presets[name]["overrides"] = row.get("overrides")
        target = _target(name, row) if scene == SCENE else None  # the targets are the dragon's
        if target:
            presets[name]["target"] = target
        presets[name].update(recommend(name, row, good, margin))
    dates = sorted(r["measured"] for r in good if r.get("measured"))
    return {"machine": machine_line(machine), "machine_details": machine,
            "measured": dates[-1] if dates else time.strftime("%Y-%m-%dT%H:%M:%S"),
            "scene": f"{scene}: {SCENES[scene].description}", "material": materials_of(presets),
            "code": ", ".join(sorted({r.get("code", "unknown") for r in good if r["name"] in presets})),
            "metric": "expected_f1 is F1@0.01 as a fraction; expected_minutes is the wall clock of the whole "
                      "reconstruct process (median of the runs); load_average is the 1-minute load before/after",
            "presets": presets}


def add_arguments(parser) -> None:
    parser.add_argument("--presets", default="draft,balanced,final", help="presets to run (default: %(default)s)")
    parser.add_argument("--out", type=Path,
                        help=f"calibration file (default: {CALIBRATION_FILE} for the {MATERIAL} material, "
                             "WORK/presets-MATERIAL.json for another)")
    parser.add_argument("--material", choices=MATERIAL_CHOICES, default=MATERIAL,
                        help="the material the presets run with (default: %(default)s, reconstruct's default)")
    parser.add_argument("--work", type=Path, default=REPO / "runs" / "bench-calibrate",
                        help="work folder for the scene and the runs (default: %(default)s)")
    parser.add_argument("--from-results", type=Path, metavar="RESULTS",
                        help="write the file from a sweep's results.jsonl (dragon rows) instead of running")
    parser.add_argument("--margin", type=float, default=1.0,
                        help="F1 points a swept setting must gain to be recommended (default: %(default)s)")
    parser.add_argument("--scenes", default=",".join(KINDS.values()),
                        help="calibration scenes to run, one per kind of lighting (default: %(default)s); "
                             "the work folder's earlier rows, else the --out file's entries, stand in for the others")
    parser.add_argument("--repeats", type=int, default=1, help="runs per preset (the median time and figures are kept)")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")


def _round(value, digits: int):
    return None if value is None else round(value, digits)


def run(args) -> int:
    emit = Emitter()
    names = [n.strip() for n in args.presets.split(",") if n.strip()]
    scenes = [n.strip() for n in args.scenes.split(",") if n.strip()]
    material = args.material
    out = args.out or (CALIBRATION_FILE if material == MATERIAL else args.work / f"presets-{material}.json")
    wrong = [n for n in scenes if n not in KINDS.values()]
    if wrong:
        raise InputError(None, f"{', '.join(wrong)} is not a calibration scene", f"choose from {', '.join(KINDS.values())}")
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        raise InputError(None, f"unknown preset {', '.join(unknown)}", f"choose from {', '.join(TARGETS)}")
    if args.from_results:
        require(args.from_results.is_file(), args.from_results, "results file not found",
                "run python -m backend bench sweep first, or leave out --from-results")
        rows = [r for r in calibration_rows(args.from_results) if r["scene"] in scenes and row_material(r) == material]
        require(any(r["name"] in names for r in rows), args.from_results,
                f"no runs of the presets with the {material} material on {', '.join(scenes)}",
                "give the results of python -m backend bench calibrate (--work WORK: WORK/results.jsonl), or "
                "--material constant for a sweep's (bench sweep --grid presets runs one constant material)")
        info = next((r["machine"] for r in rows if r.get("machine")), machine())
        rows = [r for r in rows if r["name"] in names or r["name"] not in TARGETS]
    else:
        info = machine(variant.choose(args.variant, emit))
        settings = {s.name: s for s in GRIDS["presets"]}
        # earlier rows of the work folder count for what this call does not run (one scene at a time)
        rows = [r for r in calibration_rows(args.work / "results.jsonl") if r["scene"] in KINDS.values()]
        todo = [(scene, name) for scene in scenes for name in names]
        for i, (scene, name) in enumerate(todo):
            capture = ensure(scene, args.work / "scenes", emit)
            emit("stage", stage=f"calibrate:{scene}:{name}", level=i, faces=0)
            setting = dataclasses.replace(settings[name], material=material)
            row = measure(scene, capture, setting, args.work, args.repeats, float("inf"), args.variant)
            row["machine"], row["code"], row["overrides"] = info, code_version(), PRESETS[name]
            append_result(args.work / "results.jsonl", row)
            rows = [r for r in rows if (r["scene"], r["name"], row_material(r)) != (scene, name, material)] + [row]
            emit("progress", stage="calibrate", iteration=i + 1, iterations=len(todo), fraction=(i + 1) / len(todo),
                 scene=scene, preset=name, material=material, seconds=row["seconds"], f1=row.get("f1"),
                 rc=row["rc"])
    doc = calibration(rows, info, args.margin, previous_calibration(out), material)
    require(any(d["presets"] for d in doc["kinds"].values()), None, "no preset run finished",
            f"see the logs under {args.work / 'logs'}")
    fsio.write_json(out, doc)
    shipped = material == MATERIAL
    _records.write_record(
        "calibrate" if shipped else f"calibrate-{material}",
        title="Presets calibrated" if shipped else f"Presets calibrated, {material} material",
        variant=info.get("variant"),
        context=("the Draft / Balanced / Final presets on the point-lit dragon and the HDR-lit armadillo, each "
                 f"entry of {out.name if shipped else out} with the material it ran ({MATERIAL}: reconstruct's "
                 "default, what the panel's times promise) and its commit"),
        rows=record_rows(doc),
        # the entries' commits (the file is written before the record, so the tree is dirty by then)
        commit=", ".join(sorted({c.strip()[:7] for d in doc["kinds"].values() for c in str(d.get("code") or "").split(",")
                                 if c.strip()})))
    emit("done", calibration=str(out), material=material,
         kinds={kind: {n: {k: p[k] for k in ("expected_minutes", "expected_f1")} for n, p in d["presets"].items()}
                for kind, d in doc["kinds"].items()},
         dominated=[{"kind": kind, "preset": n, "by": by} for kind, d in doc["kinds"].items()
                    for n, by in dominated(d["presets"])])
    return 0


def record_rows(doc: dict) -> list[dict]:
    """The record's table: every entry of the calibration document ``doc``, by kind's scene and
    preset, with the material, machine and commit it was measured with (a file calibrated a preset at a
    time holds entries of several runs)."""
    out = []
    for kind, d in doc["kinds"].items():
        for name, e in d["presets"].items():
            faces = e.get("faces")
            shown = "" if faces is None else f"{faces / 1000:.0f}k" if faces >= 1000 else str(faces)
            out.append({"scene": KINDS[kind], "preset": name.capitalize(), "material": entry_material(e),
                        "machine": entry_machine(e),
                        "wall min": _round(e.get("expected_minutes"), 2), "CPU min": _round(e.get("cpu_minutes"), 1),
                        "F1@0.01": _round(100 * e["expected_f1"], 2) if e.get("expected_f1") is not None else None,
                        "F1@0.005": _round(100 * e["f1_005"], 1) if e.get("f1_005") is not None else None,
                        "Chamfer-L1": _round(e.get("chamfer_l1"), 5), "held-out dB": _round(e.get("novel_psnr"), 2),
                        "relit dB": _round(e.get("relit_psnr"), 2),
                        "levels, steps, faces": ", ".join(str(v) for v in (e.get("levels"), e.get("iterations"), shown)
                                                         if v not in (None, "")),
                        "code": e.get("code")})
    return out
