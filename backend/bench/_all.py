"""``bench sweep --all``: every measurement behind bench/records (and so docs/results.md), in one command.

``JOBS`` lists, per benchmark record, the command lines that produce its figures
(``python -m backend ...``, or ``python -c`` for a mesh a job builds), with ``{out}`` the
job's folder under ``--out``, ``{data}`` the shared data and ``{report}`` the sweep's report
folder (bench/). :func:`run_all` runs them one after the other as child processes (a
benchmark's timings are only worth something alone on the machine), each command's output to
``OUT/<job>/<i>.log``. A ``bench`` command writes its own record; a job of ``reconstruct`` and
``evaluate`` commands names its runs in ``scored``, and its record is written from their
``evaluation.json`` once the job has passed. It also writes:

- ``OUT/all.json``: per job its record, commands, return codes, wall and CPU seconds, the
  load before and after, the code and the machine;
- ``OUT/all.md``: per record, the commands and what each printed apart from its JSON events.

A job whose command fails is recorded with its log's last line, and the next job runs.
``--only`` picks jobs by name; ``--list`` prints them with the hours each is expected to take
on a 2-core machine, and runs nothing."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from .. import fsio
from . import _launch, _records
from ._data import SHARED_DATA
from ._machine import code_version, machine

ARMADILLO = "{data}/meshes/stanford/armadillo_86k.obj"
FOREST = "{data}/envmaps/forest_slope_1k.hdr"
TORUS_MESH = ("python", "-c", "from backend.bench._scenes import torus; from backend.geometry.mesh import save_mesh; "
              "save_mesh('{out}/torus.ply', torus())")
TORUS = ("synth", "--out", "{out}/capture", "--overwrite", "--mesh", "{out}/torus.ply", "--up", "z", "--views", "40",
         "--resolution", "128", "--lighting", "env", "--env", FOREST, "--specular", "0.15", "--roughness", "0.35",
         "--held-out", "4", "--relit-env", "sky2")


@dataclass(frozen=True)
class Job:
    """One job: its commands, and the record (bench/records/RECORD.json) its figures go to."""

    name: str
    record: str  # the benchmark record its figures go to (a bench command writes its own)
    hours: float  # expected on a 2-core machine: the runs' time budgets and the benchmarks' last durations
    commands: tuple[tuple[str, ...], ...]
    scored: tuple[tuple[str, str], ...] = ()  # (row label, run folder): runs whose evaluation.json make the record
    title: str = ""
    context: str = ""


def _run_and_score(capture: str, run: str, *options: str) -> tuple[tuple[str, ...], ...]:
    return (("reconstruct", capture, "--out", run, "--overwrite", *options),
            ("evaluate", run, "--truth", capture, "--out", f"{run}/evaluation.json"))


JOBS = (
    Job("demo", "demo", 0.1, (("demo", "--out", "{out}"),), scored=(("demo", "{out}/run"),), title="Demo",
        context="the built-in procedural object (24 views at 128 px, two point lights per camera) reconstructed "
                "with one constant material in a 4-minute budget (`./dev.sh demo`)"),
    Job("table1", "table1", 1.0,
        (("bench", "material", "--table", "--rerun", "--effects", "auto", "--out", "{out}"),)),
    Job("geometry", "geometry", 0.4, (("bench", "geometry", "--out", "{out}"),)),
    Job("effects", "effects", 0.15, (("bench", "effects", "--out", "{out}"),)),
    Job("steps", "steps", 0.05, (("bench", "steps"),)),
    Job("samples", "samples", 0.05, (("bench", "samples", "--offset", "0.02"), ("bench", "samples", "--offset", "0.005"))),
    Job("budget", "budget", 0.1, (("bench", "budget", "--minutes", "2,1", "--out", "{out}"),)),
    Job("hdr", "hdr", 0.05, (
        ("bench", "hdr", "--steps", "6", "--configs", "sppi=0;sppi=12,guiding=none", "--out", "{out}/arma"),
        ("bench", "hdr", "--mesh", "bob", "--envmap", "sunset", "--steps", "6", "--configs",
         "sppi=0;sppi=12,guiding=none", "--out", "{out}/bob"),
        ("bench", "hdr", "--max-depth", "3", "--envmap", "forest", "--steps", "6", "--configs",
         "sppi=0;sppi=12,guiding=none", "--out", "{out}/bounce"),
        ("bench", "hdr", "--resolution", "160", "--faces", "22500", "--max-depth", "3", "--envmap", "forest",
         "--steps", "5", "--ref-rounds", "1", "--ref-spp", "64", "--ref-sppi", "16", "--configs",
         "sppi=0;sppi=7,guiding=none;sppi=12,guiding=none", "--out", "{out}/160px"))),
    Job("torus-effects", "torus-effects", 0.6, (
        TORUS_MESH, TORUS + ("--albedo", "pattern"),
        *_run_and_score("{out}/capture", "{out}/auto", "--effects", "auto", "--time-budget", "10"),
        *_run_and_score("{out}/capture", "{out}/all", "--effects", "all", "--time-budget", "10"),
        *_run_and_score("{out}/capture", "{out}/no-shadows", "--effects", "auto,-shadows", "--time-budget", "10")),
        scored=(("auto", "{out}/auto"), ("all", "{out}/all"), ("auto,-shadows", "{out}/no-shadows")),
        title="Effects by accuracy per second",
        context="a textured torus (40 views, 128 px, forest_slope), 10 minutes with the effects the cost probe selects "
                "(auto), every effect, and shadow gradients off"),
    Job("armadillo", "armadillo", 0.4, (
        ("synth", "--out", "{out}/capture", "--overwrite", "--mesh", ARMADILLO, "--up", "y", "--views", "48",
         "--resolution", "160", "--lighting", "env", "--env", FOREST, "--albedo", "pattern", "--held-out", "4",
         "--relit-env", "sky2"),
        *_run_and_score("{out}/capture", "{out}/auto", "--time-budget", "20")),
        scored=(("auto, 20 min", "{out}/auto"),), title="HDR-lit armadillo",
        context="the textured armadillo under forest_slope, 48 views at 160 px, 20 minutes; true geometry: the run's "
                "material on the true surface"),
    Job("estimated-lighting", "estimated-lighting", 0.8, (
        TORUS_MESH, TORUS + ("--albedo", "pattern"),
        *_run_and_score("{out}/capture", "{out}/captured", "--lighting", "captured", "--time-budget", "10"),
        *_run_and_score("{out}/capture", "{out}/estimate", "--lighting", "estimate", "--time-budget", "10"),
        tuple(x.replace("{out}/capture", "{out}/plain") for x in TORUS) + ("--albedo", "0.6,0.45,0.3"),
        *_run_and_score("{out}/plain", "{out}/plain-captured", "--lighting", "captured", "--time-budget", "10"),
        *_run_and_score("{out}/plain", "{out}/plain-estimate", "--lighting", "estimate", "--time-budget", "10")),
        scored=(("textured, captured map", "{out}/captured"), ("textured, estimated", "{out}/estimate"),
                ("one colour, captured map", "{out}/plain-captured"), ("one colour, estimated", "{out}/plain-estimate")),
        title="Estimated lighting",
        context="the textured torus and a one-colour one, 10 minutes each with the map given and withheld "
                "(estimated)"),
    Job("captures", "captures", 0.6, (("bench", "captures", "--out", "{out}", "--minutes", "10"),)),
    Job("realworld", "realworld", 0.6, (("bench", "realworld", "--out", "{out}"),)),
    Job("sfm", "sfm", 0.25, (("bench", "sfm", "--out", "{out}/sfm.json"),)),
    Job("masks", "masks", 0.3, (("bench", "masks", "--out", "{out}"),)),
    Job("cameras", "cameras", 0.05, (("bench", "cameras", "--out", "{out}"),)),
    Job("exposure", "exposure", 0.2, (("bench", "exposure", "--out", "{out}", "--minutes", "2.5", "--without-fit"),)),
    Job("stability", "stability", 0.1, (("bench", "stability", "--quick", "--out", "{out}"),)),
    Job("sweep", "sweep", 0.6,
        (("bench", "sweep", "--grid", "quick", "--out", "{out}", "--report", "{report}"),)),
    Job("calibrate", "calibrate", 1.8,
        (("bench", "calibrate", "--scenes", "dragon,armadillo_env", "--out", "{out}/presets.json", "--work", "{out}/work"),)),
    Job("plan", "plan", 2.5, (
        ("bench", "plan", "--calibrate", "--preset", "draft", "--out", "{out}/calibrate",
         "--gains-file", "{out}/forecast.json"),
        ("bench", "plan", "--calibrate", "--preset", "balanced", "--out", "{out}/calibrate-balanced",
         "--gains-file", "{out}/forecast.json"),
        ("bench", "plan", "--preset", "draft", "--out", "{out}/test"))),
)


def expand(command: tuple[str, ...], out: Path, report: Path) -> list[str]:
    """The child's argv: ``python -m backend ARGS`` (or ``python -c``), placeholders filled."""
    args = [a.format(out=out, data=SHARED_DATA, report=report) for a in command]
    return [sys.executable] + (args[1:] if args[0] == "python" else ["-m", "backend", *args])


def printed(log: Path) -> str:
    """What a command printed apart from its JSON-lines events: its tables and summaries."""
    lines = log.read_text(errors="replace").splitlines() if log.is_file() else []
    return "\n".join(line for line in lines if line.strip() and not line.lstrip().startswith('{"event"'))


def run_job(job: Job, out: Path, report: Path) -> dict:
    """Run ``job``'s commands in order (stopping at the first that fails); its record."""
    folder = out / job.name
    folder.mkdir(parents=True, exist_ok=True)
    steps = []
    for i, command in enumerate(job.commands):
        argv, log = expand(command, folder, report), folder / f"{i}.log"
        child = _launch.run(argv, log=log)
        steps.append({"command": " ".join(["python", *argv[1:]]), "rc": child.rc, "log": str(log),
                      "seconds": round(child.seconds, 1), "cpu_seconds": round(child.cpu_seconds, 1),
                      "load_before": round(child.load_before, 2), "load_after": round(child.load_after, 2)})
        if child.rc != 0:
            tail = (printed(log).splitlines() or ["(no output)"])[-1]
            steps[-1]["error"] = tail[-500:]
            break
    record = {"job": job.name, "record": job.record, "steps": steps, "rc": max((s["rc"] for s in steps), default=0)}
    if job.scored and record["rc"] == 0:
        write_scored(job, folder)
    return record


def scored_row(label: str, run: Path) -> dict:
    """A run's row: faces and minutes from its report.json, scores from its evaluation.json."""
    report = json.loads((run / "report.json").read_text())
    evaluation = json.loads((run / "evaluation.json").read_text()) if (run / "evaluation.json").is_file() else \
        json.loads((run.parent / "evaluation.json").read_text())
    g, views = evaluation.get("geometry", {}), evaluation.get("views", {})

    def view(name):
        psnr = (views.get(name) or {}).get("psnr")
        return None if psnr is None else round(psnr, 2)

    albedo = (evaluation.get("albedo") or {}).get("rmse")
    return {"run": label, "faces": report["result"]["faces"], "minutes": round(report["timings"]["total"] / 60, 1),
            "F1@0.01": round(g["f1@0.01"], 2), "F1@0.005": round(g["f1@0.005"], 2),
            "Chamfer-L1": round(g["chamfer_l1"], 5), "held-out dB": view("held_out"), "relit dB": view("relit"),
            "true geometry dB": view("true_geometry"), "albedo RMSE": None if albedo is None else round(albedo, 3)}


def write_scored(job: Job, folder: Path) -> Path:
    """The record of a job whose commands are ``reconstruct`` and ``evaluate``: one row per run."""
    rows = [scored_row(label, Path(run.format(out=folder))) for label, run in job.scored]
    rows = [{k: v for k, v in r.items() if any(x.get(k) is not None for x in rows)} for r in rows]
    commands = [" ".join(["python", *expand(c, Path("OUT"), Path("bench"))[1:]]) for c in job.commands]
    return _records.write_record(job.record, title=job.title, context=job.context, rows=rows,
                                 command=f"python -m backend bench sweep --all --only {job.name} --out OUT",
                                 commands=commands)


def markdown(records: list[dict], code: str, when: str) -> str:
    parts = [f"# Regenerated figures (code {code}, {when})\n"]
    for name in dict.fromkeys(r["record"] for r in records):
        parts.append(f"## {name}\n")
        for r in (r for r in records if r["record"] == name):
            for s in r["steps"]:
                status = "" if s["rc"] == 0 else f" - **failed ({s['rc']})**: {s.get('error', '')}"
                parts.append(f"`{s['command']}` ({s['seconds'] / 60:.1f} min){status}\n")
                text = printed(Path(s["log"]))
                if text:
                    parts.append("```\n" + "\n".join(text.splitlines()[-60:]) + "\n```\n")
    return "\n".join(parts)


def select(only: str | None) -> list[Job]:
    """The jobs named in ``only`` (comma-separated), else all; raises ValueError naming unknown ones."""
    if not only:
        return list(JOBS)
    names = [n.strip() for n in only.split(",") if n.strip()]
    unknown = [n for n in names if n not in {j.name for j in JOBS}]
    if unknown:
        raise ValueError(f"unknown job {', '.join(unknown)}; choose from {', '.join(j.name for j in JOBS)}")
    return [j for j in JOBS if j.name in names]


def listing(jobs: list[Job]) -> str:
    rows = [f"{j.name:20s} {j.hours:4.1f} h  bench/records/{j.record}.json" for j in jobs]
    return "\n".join(rows + [f"{'total':20s} {sum(j.hours for j in jobs):4.1f} h"])


def run_all(jobs: list[Job], out: Path, report: Path, emit) -> list[dict]:
    out.mkdir(parents=True, exist_ok=True)
    code, when, records = code_version(), time.strftime("%Y-%m-%dT%H:%M:%S"), []
    for i, job in enumerate(jobs):
        emit("stage", stage=f"all:{job.name}", level=i, faces=0)
        records.append(run_job(job, out, report))
        doc = {"code": code, "measured": when, "machine": machine(None), "jobs": records}
        fsio.write_json(out / "all.json", doc)
        fsio.write_text(out / "all.md", markdown(records, code, when))
        emit("progress", stage="all", iteration=i + 1, iterations=len(jobs), fraction=(i + 1) / len(jobs),
             job=job.name, rc=records[-1]["rc"])
    return records

