"""``bench sweep --all``: every measurement behind docs/results.md and bench/, in one command.

``JOBS`` lists, per section of docs/results.md, the command lines that produce its figures
(``python -m backend ...``, or ``python -c`` for a mesh a section builds), with ``{out}`` the
job's folder under ``--out``, ``{data}`` the shared data and ``{report}`` the sweep's report
folder (bench/). :func:`run_all` runs them one after the other as child processes (a
benchmark's timings are only worth something alone on the machine), each command's output to
``OUT/<job>/<i>.log``, and writes:

- ``OUT/all.json``: per job its section, commands, return codes, wall and CPU seconds, the
  load before and after, the code and the machine;
- ``OUT/all.md``: per section, the commands and what each printed apart from its JSON events
  (the benchmarks' tables), to carry into docs/results.md.

A job whose command fails is recorded with its log's last line, and the next job runs.
``--only`` picks jobs by name; ``--list`` prints them with the hours each is expected to take
on a 2-core machine, and runs nothing."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

from .. import fsio
from . import _launch
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
    name: str
    section: str  # the heading in docs/results.md its figures belong to
    hours: float  # expected on a 2-core machine: the runs' time budgets and the benchmarks' last durations
    commands: tuple[tuple[str, ...], ...]


def _run_and_score(capture: str, run: str, *options: str) -> tuple[tuple[str, ...], ...]:
    return (("reconstruct", capture, "--out", run, "--overwrite", *options),
            ("evaluate", run, "--truth", capture))


JOBS = (
    Job("demo", "Demo", 0.1, (("demo", "--out", "{out}"),)),
    Job("table1", "Table 1: shape and material (the paper's table)", 1.0,
        (("bench", "material", "--table", "--rerun", "--effects", "auto", "--out", "{out}"),)),
    Job("geometry", "Geometry benchmark", 0.4, (("bench", "geometry", "--out", "{out}"),)),
    Job("effects", "Effects: simulate only what a scene calls for", 0.15, (("bench", "effects", "--out", "{out}"),)),
    Job("hdr", "HDR-lit step cost", 0.05, (
        ("bench", "hdr", "--steps", "6", "--configs", "sppi=0;sppi=12,guiding=none", "--out", "{out}/arma"),
        ("bench", "hdr", "--mesh", "bob", "--envmap", "sunset", "--steps", "6", "--configs",
         "sppi=0;sppi=12,guiding=none", "--out", "{out}/bob"),
        ("bench", "hdr", "--max-depth", "3", "--envmap", "forest", "--steps", "6", "--configs",
         "sppi=0;sppi=12,guiding=none", "--out", "{out}/bounce"),
        ("bench", "hdr", "--resolution", "160", "--faces", "22500", "--max-depth", "3", "--envmap", "forest",
         "--steps", "5", "--ref-rounds", "1", "--ref-spp", "64", "--ref-sppi", "16", "--configs",
         "sppi=0;sppi=7,guiding=none;sppi=12,guiding=none", "--out", "{out}/160px"))),
    Job("torus-effects", "Effects by accuracy per second (issue #24)", 0.6, (
        TORUS_MESH, TORUS + ("--albedo", "pattern"),
        *_run_and_score("{out}/capture", "{out}/auto", "--effects", "auto", "--time-budget", "10"),
        *_run_and_score("{out}/capture", "{out}/all", "--effects", "all", "--time-budget", "10"),
        *_run_and_score("{out}/capture", "{out}/no-shadows", "--effects", "auto,-shadows", "--time-budget", "10"))),
    Job("armadillo", "Effects by accuracy per second (issue #24)", 0.4, (
        ("synth", "--out", "{out}/capture", "--overwrite", "--mesh", ARMADILLO, "--up", "y", "--views", "48",
         "--resolution", "160", "--lighting", "env", "--env", FOREST, "--albedo", "pattern", "--held-out", "4",
         "--relit-env", "sky2"),
        *_run_and_score("{out}/capture", "{out}/auto", "--time-budget", "20"))),
    Job("estimated-lighting", "Estimated lighting (issue #22)", 0.8, (
        TORUS_MESH, TORUS + ("--albedo", "pattern"),
        *_run_and_score("{out}/capture", "{out}/captured", "--lighting", "captured", "--time-budget", "10"),
        *_run_and_score("{out}/capture", "{out}/estimate", "--lighting", "estimate", "--time-budget", "10"),
        tuple(x.replace("{out}/capture", "{out}/plain") for x in TORUS) + ("--albedo", "0.6,0.45,0.3"),
        *_run_and_score("{out}/plain", "{out}/plain-captured", "--lighting", "captured", "--time-budget", "10"),
        *_run_and_score("{out}/plain", "{out}/plain-estimate", "--lighting", "estimate", "--time-budget", "10"))),
    Job("captures", "Real captures on the current code (2026-11-30)", 0.6, (("bench", "captures", "--out", "{out}", "--minutes", "10"),)),
    Job("realworld", "Real-world captures", 0.6, (("bench", "realworld", "--out", "{out}"),)),
    Job("sfm", "Real-world captures", 0.25, (("bench", "sfm", "--out", "{out}/sfm.json"),)),
    Job("stability", "Numerical stability", 0.1, (("bench", "stability", "--quick", "--out", "{out}"),)),
    Job("sweep", "Accuracy versus time: the sweep and the presets", 0.6,
        (("bench", "sweep", "--grid", "quick", "--out", "{out}", "--report", "{report}"),)),
    Job("calibrate", "Accuracy versus time: the sweep and the presets", 1.8,
        (("bench", "calibrate", "--scenes", "dragon,armadillo_env", "--out", "{out}/presets.json", "--work", "{out}/work"),)),
    Job("plan", "Predicted time: a cost model per capture (issue #23)", 2.5, (
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
    return {"job": job.name, "section": job.section, "steps": steps,
            "rc": max((s["rc"] for s in steps), default=0)}


def markdown(records: list[dict], code: str, when: str) -> str:
    parts = [f"# Regenerated figures (code {code}, {when})\n"]
    for section in dict.fromkeys(r["section"] for r in records):
        parts.append(f"## {section}\n")
        for r in (r for r in records if r["section"] == section):
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
    rows = [f"{j.name:20s} {j.hours:4.1f} h  {j.section}" for j in jobs]
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

