"""``bench sweep --all``: the registry covers docs/results.md, and the runner runs real commands,
records them and gathers what they printed."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from backend.bench import _all
from tests.helpers import REPO, run_cli

RESULTS = REPO / "docs" / "results.md"


def test_every_benchmark_the_document_quotes_has_a_job():
    text = RESULTS.read_text()
    documented = set(re.findall(r"`bench ([a-z]+)", text))
    run = {c[1] for job in _all.JOBS for c in job.commands if c[0] == "bench"}
    assert documented and documented <= run | {"results"}, documented - run


def test_a_bench_that_writes_one_file_is_not_pointed_at_its_job_folder():
    # the job folder holds the commands' logs: a JSON report written over it fails the job
    files = {"sfm", "hdr"}  # their --out is a JSON file, the others' a work folder
    for job in _all.JOBS:
        for command in job.commands:
            if command[0] == "bench" and command[1] in files:
                assert command[command.index("--out") + 1] != "{out}", (job.name, command)


def test_list_prints_the_jobs_and_runs_nothing(tmp_path):
    proc = run_cli("bench", "sweep", "--all", "--list", "--out", tmp_path / "all", timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.strip().splitlines()
    assert [line.split()[0] for line in lines[:-1]] == [j.name for j in _all.JOBS]
    assert lines[-1].startswith("total") and not (tmp_path / "all").exists()
    bad = run_cli("bench", "sweep", "--all", "--only", "nope", "--out", tmp_path / "all", timeout=120)
    assert bad.returncode == 2 and "unknown job nope" in bad.stderr and "Traceback" not in bad.stderr


def test_a_job_of_reconstruct_and_evaluate_writes_its_record_from_the_evaluation(tmp_path):
    job = _all.Job("tiny-scored", "tiny-scored", 0.01, (
        ("synth", "--out", "{out}/capture", "--views", "6", "--resolution", "24", "--spp", "8", "--held-out", "2"),
        *_all._run_and_score("{out}/capture", "{out}/run", "--init", "sphere", "--iterations", "6", "--max-size", "24",
                             "--coarse-size", "24", "--initial-faces", "500", "--spp", "4", "--effects", "specular",
                             "--material", "known:0.6,0.6,0.6:0.25:0.35")),
        scored=(("tiny", "{out}/run"),), title="Tiny", context="a tiny capture")
    record, = _all.run_all([job], tmp_path, tmp_path / "report", lambda *a, **k: None)
    assert record["rc"] == 0, record["steps"][-1].get("error")
    written = json.loads((Path(os.environ["SFT_RECORDS"]) / "tiny-scored.json").read_text())
    row, = written["figures"]["rows"]
    assert row["run"] == "tiny" and row["faces"] > 0 and 0 < row["F1@0.01"] <= 100 and row["held-out dB"] > 5
    assert written["command"] == "python -m backend bench sweep --all --only tiny-scored --out OUT"
    assert len(written["commands"]) == 3 and written["commands"][2].startswith("python -m backend evaluate OUT/")


def test_the_runner_records_each_command_and_stops_a_job_at_its_first_failure(tmp_path):
    good = _all.Job("tiny", "demo", 0.01, (
        ("synth", "--out", "{out}/capture", "--views", "4", "--resolution", "16", "--spp", "4", "--held-out", "0"),
        ("python", "-c", "print('| views | 4 |')")))
    bad = _all.Job("broken", "stability", 0.01, (
        ("reconstruct", "{out}/missing", "--out", "{out}/run"),
        ("python", "-c", "print('never')")))
    events = []
    records = _all.run_all([good, bad], tmp_path, tmp_path / "report", lambda *a, **k: events.append((a, k)))
    ok, failed = records
    assert ok["rc"] == 0 and len(ok["steps"]) == 2 and (tmp_path / "tiny" / "capture" / "capture.json").is_file()
    assert all(s["seconds"] >= 0 and s["cpu_seconds"] >= 0 for s in ok["steps"])
    assert failed["rc"] == 2 and len(failed["steps"]) == 1 and "missing" in failed["steps"][0]["error"]
    doc = json.loads((tmp_path / "all.json").read_text())
    assert [j["job"] for j in doc["jobs"]] == ["tiny", "broken"] and doc["code"]
    md = (tmp_path / "all.md").read_text()
    assert "## demo" in md and "| views | 4 |" in md and "**failed (2)**" in md and "never" not in md
