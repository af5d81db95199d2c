"""The time budget is the command's wall clock: a budgeted run ends within its budget plus a
few seconds, measured from the process's start to its exit, with its first geometry step
early; step costs measured once are reused from beside the capture."""

from __future__ import annotations

import json
import shutil
import time

from backend.planning.step_costs import CACHE
from tests.helpers import run_cli


def _events(run):
    return [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines() if line.strip()]


def test_a_budgeted_run_ends_within_its_wall_clock(tiny_capture, tmp_path):
    budget_s = 24.0
    run = tmp_path / "run"
    start = time.perf_counter()
    proc = run_cli("reconstruct", tiny_capture, "--out", run, "--time-budget", budget_s / 60, "--init", "sphere",
                   "--initial-faces", 320, "--track-accuracy", timeout=300)
    wall = time.perf_counter() - start
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert wall <= budget_s + 10.0, wall  # process start to exit: imports, scoring and the results included
    events = _events(run)
    first = next(e["time"] for e in events if e["event"] == "stage" and e.get("stage") == "geometry")
    assert first < 15.0, first
    report = json.loads((run / "report.json").read_text())
    assert report["timings"]["total"] <= budget_s + 5.0
    assert report["timings"]["accuracy"] > 0  # the held-out scoring ran, inside the budget
    assert (run / "result.glb").is_file()


def test_step_costs_are_measured_once_per_capture(tiny_capture, tmp_path):
    capture = tmp_path / "capture"
    shutil.copytree(tiny_capture, capture)
    options = ("--init", "sphere", "--initial-faces", 320, "--iterations", 4, "--max-size", 16, "--coarse-size", 16,
               "--material", "constant")

    def planned(run):
        proc = run_cli("reconstruct", capture, "--out", run, *options, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return next(e for e in _events(run) if e["event"] == "preset" and e.get("plan"))

    first = planned(tmp_path / "first")
    assert (capture / CACHE).is_file()
    second = planned(tmp_path / "second")
    assert second["plan"]["costs"]["points"] == first["plan"]["costs"]["points"]
    assert second["plan"]["costs"]["seconds"] < min(0.1, first["plan"]["costs"]["seconds"] / 3)  # read, not timed
