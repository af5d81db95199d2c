"""``bench plan``: a real preset run on a tiny capture, its promise read back and compared."""

from __future__ import annotations

import json
import os
from pathlib import Path

from backend.bench import plan as bench_plan
from tests.helpers import run_cli


def test_bench_plan_compares_the_promise_with_the_run(tmp_path):
    out = tmp_path / "bench"
    proc = run_cli("bench", "plan", "--out", out, "--captures", "tiny", "--iterations", 6, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    doc = json.loads((out / "plan.json").read_text())
    (row,) = doc["rows"]
    assert row["rc"] == 0 and row["capture"] == "tiny" and row["lighting_kind"] == "point"
    assert row["predicted_minutes"] > 0 and row["measured_minutes"] > 0
    # the error of the promise against the process's wall clock (both rounded in the file)
    slack = 0.6 / row["seconds"] + 0.01
    assert abs(row["time_error"] - (row["predicted_minutes"] * 60 / row["seconds"] - 1)) < slack
    assert row["effects"] is not None and set(row["plan"]) == {"geometry_s", "material_s", "polish_s", "fixed_s"}
    assert doc["summary"]["runs"] == 1 and doc["summary"]["time_median_abs_error"] == abs(row["time_error"])
    assert "tiny" in proc.stdout and "predicted min" in proc.stdout
    record = json.loads((Path(os.environ["SFT_RECORDS"]) / "plan.json").read_text())
    (recorded,) = [r for r in record["figures"]["rows"] if r["capture"] == "tiny"]
    assert recorded["predicted min"] == row["predicted_minutes"] and record["figures"]["scalars"]["runs"] >= 1
    # --replan: the same model on the recorded step costs gives the run's own promise back
    proc = run_cli("bench", "plan", "--out", out, "--replan", timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (again,) = json.loads((out / "replan.json").read_text())["rows"]
    assert again["recorded_minutes"] == row["predicted_minutes"]
    # both rounded to 0.01 min, from step costs stored to 0.1 ms: one rounding step apart at most
    assert abs(again["predicted_minutes"] - row["predicted_minutes"]) <= 0.011


def test_replan_needs_a_finished_bench(tmp_path):
    proc = run_cli("bench", "plan", "--out", tmp_path / "none", "--replan", timeout=120)
    assert proc.returncode == 2 and "no finished bench plan here" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_summary_counts_what_is_within_the_targets():
    rows = [{"time_error": 0.1, "f1_error": 0.01}, {"time_error": -0.4, "f1_error": -0.05}, {"time_error": 0.25}]
    s = bench_plan.summary(rows)
    assert s["time_median_abs_error"] == 0.25 and s["time_worst_abs_error"] == 0.4
    assert s["time_within"] == 2 and s["f1_within"] == 1 and s["runs"] == 3
