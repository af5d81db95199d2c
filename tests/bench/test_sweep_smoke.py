"""The sweep harness end to end on the tiny scene with its two smoke settings (real synth,
real reconstruct child processes, real renders), then the report and the calibration file
built from those rows."""

from __future__ import annotations

import argparse
import json
import math
import os

import pytest

from backend.bench import _pareto, calibrate, sweep
from backend.geometry.mesh import load_mesh
from backend.planning.presets import preset_for_budget


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep")
    parser = argparse.ArgumentParser()
    sweep.add_arguments(parser)
    args = parser.parse_args(["--grid", "smoke", "--scenes", "tiny", "--out", str(root / "work"),
                              "--report", str(root / "report"), "--repeats", "1", "--eval-spp", "16"])
    assert sweep.run(args) == 0
    return root


def test_the_sweep_writes_its_record_where_sft_records_points(swept):
    record = json.loads((sweep.Path(os.environ["SFT_RECORDS"]) / "sweep.json").read_text())
    assert record["benchmark"] == "sweep" and record["commit"] and record["machine"]["cores"] >= 1
    assert sorted(r["setting"] for r in record["figures"]["rows"]) == ["smoke-a", "smoke-b"]
    assert all(p.endswith("pareto_tiny.png") for p in record["plots"])


def test_every_setting_is_measured_and_scored(swept):
    rows = sweep.load_results(swept / "work" / "results.jsonl")
    assert sorted(r["name"] for r in rows) == ["smoke-a", "smoke-b"]
    for r in rows:
        assert r["rc"] == 0, r.get("error")
        assert r["seconds"] > 0 and r["cpu_seconds"] > 0 and r["peak_mb"] > 50
        assert 0 < r["f1"] <= 100 and 0 < r["chamfer_l1"] < 0.5
        assert math.isfinite(r["novel_psnr"]) and math.isfinite(r["relit_psnr"]) and r["relit_psnr"] > 10
        assert r["knobs"]["max_size"] == {"smoke-a": 24, "smoke-b": 32}[r["name"]]
        assert r["machine"]["cores"] >= 1 and r["machine"]["variant"]
        assert load_mesh(sweep.Path(r["run"]) / "result.ply").n_faces > 0


def test_report_and_plot_are_written(swept):
    report = swept / "report"
    text = (report / "report.md").read_text()
    assert "## tiny" in text and "Pareto front" in text and "smoke-a" in text and "load average" in text
    png = (report / "pareto_tiny.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    rows = json.loads((report / "results.json").read_text())
    front = _pareto.front([r["seconds"] for r in rows], [r["f1"] for r in rows])
    assert front and all(rows[i]["name"] in text for i in front)


def test_result_renders_score_the_truth_higher_than_a_sphere(swept):
    """The scoring function itself: the true mesh scores far better than a wrong shape."""
    from backend.capture.load import load_capture
    from backend.geometry.mesh import Mesh, save_mesh
    from backend.synth.procedural import icosphere

    capture = load_capture(swept / "work" / "scenes" / "tiny")
    scores = {}
    for name, mesh in (("truth", load_mesh(capture.path(capture.ground_truth["mesh"]))),
                       ("sphere", icosphere(3, 0.2))):
        run = swept / f"fake-{name}"
        save_mesh(run / "result.ply", Mesh(mesh.vertices, mesh.faces))
        (run / "report.json").write_text(json.dumps({"material": {"albedo": [0.6] * 3, "specular": [0.25],
                                                                  "roughness": [0.35]}}))
        scores[name] = sweep.view_scores(run, capture, spp=64)
    # the tiny capture's own noise (16 spp) caps the truth's scores near 30 and 27 dB
    assert scores["truth"]["novel_psnr"] > 27 and scores["truth"]["relit_psnr"] > 24
    assert scores["truth"]["novel_psnr"] > scores["sphere"]["novel_psnr"] + 5


def test_calibration_file_from_rows(swept, tmp_path):
    rows = sweep.load_results(swept / "work" / "results.jsonl")
    as_presets = [dict(r, scene="dragon", name=n) for r, n in zip(sorted(rows, key=lambda r: r["name"]),
                                                                 ("draft", "balanced"))]
    doc = calibrate.calibration(as_presets, as_presets[0]["machine"], material=calibrate.row_material(as_presets[0]))
    assert isinstance(doc["machine"], str) and "cores" in doc["machine"]
    assert set(doc["presets"]) == {"draft", "balanced"}
    draft = doc["presets"]["draft"]
    assert 0 < draft["expected_f1"] <= 1 and draft["expected_minutes"] > 0
    assert draft["target"]["minutes"] == 3.0
    path = tmp_path / "presets.json"
    path.write_text(json.dumps(doc))
    fastest = min(doc["presets"], key=lambda n: doc["presets"][n]["expected_minutes"])
    assert preset_for_budget(1e-3, path) == fastest


def test_a_repeated_setting_reports_the_median_of_its_runs(swept, tmp_path):
    """Repeats score every run before the next overwrites its folder: the row's F1 and held-out
    PSNR are the runs' medians (calibrate's --repeats keeps them), with each run's listed."""
    setting = sweep.GRIDS["smoke"][0]
    row = sweep.measure("tiny", swept / "work" / "scenes" / "tiny", setting, tmp_path, repeats=3,
                        repeat_under=float("inf"), eval_spp=16)
    assert row["rc"] == 0 and row["repeats"] == 3 and len(row["seconds_runs"]) == 3
    assert len(row["f1_runs"]) == 3 and len(row["novel_psnr_runs"]) == 3
    assert row["f1"] == sorted(row["f1_runs"])[1]
    assert row["novel_psnr"] == sorted(row["novel_psnr_runs"])[1]
    assert row["seconds"] == sorted(row["seconds_runs"])[1]
    assert isinstance(row["iterations"], int) and isinstance(row["levels"], int)


def test_median_scores_keep_counts_whole_and_the_last_material():
    scored = [{"f1": 90.0, "iterations": 100, "levels": 2, "material": {"albedo": [0.1]}, "novel_psnr": None},
              {"f1": 94.0, "iterations": 130, "levels": 3, "material": {"albedo": [0.2]}, "novel_psnr": 22.0}]
    out = sweep.median_scores(scored)
    assert out["f1"] == 92.0 and out["iterations"] == 100 and out["levels"] == 2
    assert out["novel_psnr"] == 22.0 and out["material"] == {"albedo": [0.2]}
