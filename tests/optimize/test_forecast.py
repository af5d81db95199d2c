"""The accuracy probe and the predicted held-out PSNR (planning/accuracy_forecast.py), on real renders:
the probe's figure is the tracker's, on a copy of the capture; the prediction is probe + gain;
a run's ``preset`` event and ``--plan`` carry it."""

from __future__ import annotations

import dataclasses
import json
import pytest

from backend.planning import accuracy_forecast as forecast
from tests.helpers import run_cli


@pytest.fixture(scope="module")
def tiny(tiny_capture):
    from backend import variant

    variant.choose()
    from backend.capture.load import load_capture
    from backend.optimize.config import ReconstructConfig

    config = ReconstructConfig(max_size=48, coarse_size=24, initial_faces=500, material="staged")
    return load_capture(tiny_capture), config


def test_the_probe_scores_the_held_out_views_as_the_tracker_does(tiny):
    capture, config = tiny
    before = (len(capture.frames), capture.environment)
    probed = forecast.probe(capture, config)
    assert probed is not None and probed["source"] == "ground truth" and probed["views"] == 2
    assert 12.0 < probed["psnr"] < 45.0  # a fitted grey-to-diffuse material on the visual hull
    assert probed["cycles"] >= 2 and probed["faces"] <= 500 and probed["seconds"] > 0
    assert probed["lighting_kind"] == "point"  # the tiny capture's point lights, recorded with the probe
    assert probed["size"] == 48  # the scored images' long side: the capture's 48 px, under accuracy_size
    assert (len(capture.frames), capture.environment) == before  # the capture is not touched


def test_the_probe_is_repeatable_and_needs_held_out_views_and_the_staged_material(tiny):
    capture, config = tiny
    a, b = forecast.probe(capture, config), forecast.probe(capture, config)
    assert a["psnr"] == pytest.approx(b["psnr"], abs=0.05)  # seeded renders and fits
    assert forecast.probe(capture, dataclasses.replace(config, material="auto")) is None
    bare = dataclasses.replace(capture, ground_truth=None)  # 8 views: too few to hold out every 8th
    assert forecast.probe(bare, config) is None


def test_the_prediction_is_the_probe_plus_the_presets_gain(tmp_path):
    path = tmp_path / "forecast.json"
    assert forecast.load_gains(path) == {}  # absent: nothing predicted
    path.write_text(json.dumps({"presets": {"draft": {"gain_db": 2.5}, "final": {"gain_db": "?"}}}))
    gains = forecast.load_gains(path)
    assert set(gains) == {"draft"}
    assert forecast.predicted_psnr({"psnr": 20.0}, "draft", gains) == 22.5
    assert forecast.predicted_psnr({"psnr": 20.0}, "balanced", gains) is None
    assert forecast.predicted_psnr(None, "draft", gains) is None


def test_one_median_serves_every_kind_of_lighting_and_the_spread_has_a_floor(tmp_path):
    path = tmp_path / "forecast.json"
    path.write_text(json.dumps({"presets": {"draft": {
        "gain_db": 3.0, "spread_db": 0.4,
        "kinds": {"point": {"gain_db": 5.0, "spread_db": 0.2, "captures": ["a", "b"]}}}}}))
    gains = forecast.load_gains(path)
    for kind in ("point", "environment", None):  # the kinds' medians are a record, not the prediction
        assert forecast.predicted_psnr({"psnr": 20.0, "lighting_kind": kind}, "draft", gains) == 23.0
    # a spread narrower than a run's own run-to-run spread is not promised
    assert forecast.gain(gains, "draft") == (3.0, forecast.SPREAD_FLOOR_DB)
    assert forecast.gain(gains, "final") is None


def test_the_line_in_the_probe_is_recorded_not_used(tmp_path):
    """The calibration records a line of the gain in the probe's PSNR; it predicted worse on
    captures it had not seen, so the median predicts."""
    path = tmp_path / "forecast.json"
    line = {"intercept": -4.0, "slope": 0.4, "probe_range": [16.0, 28.0], "spread_db": 1.5}
    path.write_text(json.dumps({"presets": {"draft": {"gain_db": 3.0, "spread_db": 3.4, "line": line}}}))
    gains = forecast.load_gains(path)
    assert forecast.gain(gains, "draft") == (3.0, 3.4)
    assert forecast.predicted_psnr({"psnr": 25.0}, "draft", gains) == 28.0
    assert forecast.fit_line([(20.0, 3.0), (20.0, 4.0), (20.0, 5.0)]) is None  # one probe: no slope
    assert forecast.fit_line([(18.0, 2.0), (22.0, 4.0)]) is None  # too few


def test_a_capture_scored_finer_than_the_calibrations_gets_a_floor_not_a_spread(tmp_path):
    """The gain holds at the sizes it was calibrated at; a probe scored at a finer size says so
    (a floor, "21+ dB"), a coarser one drops the spread."""
    from backend.planning.time_plan import psnr_text

    path = tmp_path / "forecast.json"
    captures = {"a": {"gain_db": 3.0, "probe_size": 48}, "b": {"gain_db": 2.0, "probe_size": 64}}
    path.write_text(json.dumps({"presets": {"draft": {"gain_db": 3.0, "spread_db": 2.0, "captures": captures},
                                            "balanced": {"gain_db": 2.5, "captures": {"c": {"gain_db": 1.0}}}}}))
    gains = forecast.load_gains(path)
    assert forecast.calibrated_sizes(gains) == (48, 64)  # over every preset's captures that record one
    assert forecast.extrapolated({"psnr": 18.0, "size": 128}, gains) == "finer"
    assert forecast.extrapolated({"psnr": 18.0, "size": 32}, gains) == "coarser"
    assert forecast.extrapolated({"psnr": 18.0, "size": 64}, gains) is None
    assert forecast.extrapolated({"psnr": 18.0}, gains) is None  # an older probe: size unknown
    assert forecast.extrapolated(None, gains) is None
    path.write_text(json.dumps({"presets": {"draft": {"gain_db": 3.0, "captures": {"a": {"gain_db": 3.0}}}}}))
    assert forecast.extrapolated({"psnr": 18.0, "size": 128}, forecast.load_gains(path)) is None  # no sizes
    assert psnr_text(21.2, 2.2) == "\u2248 21 \u00b1 2 dB"
    assert psnr_text(21.2, None, "finer") == "21+ dB"
    assert psnr_text(21.2, 2.2, "coarser") == "\u2248 21 dB"
    assert psnr_text(None, 2.2) is None


def test_a_finer_capture_s_plan_shows_its_prediction_as_a_floor(tmp_path):
    """``reconstruct --plan`` on a capture scored at 96 px, finer than the shipped calibration's."""
    capture = tmp_path / "capture96"
    run_cli("synth", "--out", capture, "--views", 8, "--resolution", 96, "--spp", 16, "--held-out", 2, check=True)
    settings = json.dumps({"max_size": 96, "coarse_size": 24, "initial_faces": 500})
    proc = run_cli("reconstruct", capture, "--out", tmp_path / "plan", "--plan", "--preset", "draft",
                   env={"SFT_RECONSTRUCT_SETTINGS": settings}, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    event = json.loads(proc.stdout.strip().splitlines()[-1])
    gains = forecast.load_gains()
    assert event["probe"]["size"] == 96 > forecast.calibrated_sizes(gains)[1]
    draft = event["presets"]["draft"]
    assert draft["psnr_extrapolated"] == "finer" and draft["psnr_spread"] is None
    assert f"({draft['predicted_psnr']:.0f}+ dB)" in event["line"]


def test_calibration_writes_the_median_gain_and_records_each_kind_of_lightings(tmp_path):
    from backend.bench import plan as bench_plan

    rows = [{"capture": "p1", "lighting_kind": "point", "probe_psnr": 20.0, "psnr": 23.0, "gain_db": 3.0,
             "probe_size": 48},
            {"capture": "p2", "lighting_kind": "point", "probe_psnr": 20.0, "psnr": 26.0, "gain_db": 6.0},
            {"capture": "p3", "lighting_kind": "point", "probe_psnr": 20.0, "psnr": 25.0, "gain_db": 5.0},
            {"capture": "e1", "lighting_kind": "environment", "probe_psnr": 18.0, "psnr": 20.5, "gain_db": 2.5},
            {"capture": "e2", "lighting_kind": "environment", "probe_psnr": 18.0, "psnr": 21.0, "gain_db": 3.0},
            {"capture": "x", "lighting_kind": "point", "rc": 1}]  # a failed run counts nowhere
    path = tmp_path / "forecast.json"
    path.write_text(json.dumps({"presets": {"balanced": {"gain_db": 2.0, "spread_db": 1.0, "captures": {}}}}))
    bench_plan.write_gain(path, "draft", rows, {"code": "abc", "measured": "now", "machine": {}})
    entry = forecast.load_gains(path)["draft"]
    assert entry["gain_db"] == 3.0 and entry["spread_db"] == 3.0  # over all five: 2.5, 3, 3, 5, 6
    assert entry["kinds"]["point"] == {"gain_db": 5.0, "spread_db": 2.0, "captures": ["p1", "p2", "p3"]}
    assert entry["kinds"]["environment"]["gain_db"] == 2.75 and entry["kinds"]["environment"]["captures"] == ["e1", "e2"]
    assert forecast.load_gains(path)["balanced"]["gain_db"] == 2.0  # other presets kept
    assert entry["captures"]["p1"]["probe_size"] == 48 and entry["captures"]["p2"]["probe_size"] is None
    # the line through (20, 4.67 mean) and (18, 2.75 mean): slope 0.96, largest residual 1.67
    assert entry["line"]["slope"] == pytest.approx(0.9583, abs=1e-3)
    assert entry["line"]["probe_range"] == [18.0, 20.0] and entry["line"]["spread_db"] == pytest.approx(1.67)



def test_the_shipped_gains_name_their_captures_and_code():
    gains = forecast.load_gains()
    assert gains, "backend/forecast.json: run python -m backend bench plan --calibrate --preset draft"
    for entry in gains.values():
        assert len(entry["captures"]) >= 4 and entry["spread_db"] >= 0 and entry["code"]
        median = sorted(c["gain_db"] for c in entry["captures"].values())
        assert min(median) <= entry["gain_db"] <= max(median)
        line = entry.get("line")  # fitted on the same captures: within their probes, its spread their residuals'
        if line:
            probes = [c["probe_psnr"] for c in entry["captures"].values()]
            assert line["probe_range"] == [round(min(probes), 2), round(max(probes), 2)]
            residuals = [abs(c["gain_db"] - line["intercept"] - line["slope"] * c["probe_psnr"])
                         for c in entry["captures"].values()]
            assert line["spread_db"] == pytest.approx(max(residuals), abs=0.02)
        for kind, sub in (entry.get("kinds") or {}).items():
            own = [entry["captures"][name]["gain_db"] for name in sub["captures"]]
            assert all(entry["captures"][name]["lighting_kind"] == kind for name in sub["captures"])
            assert min(own) <= sub["gain_db"] <= max(own)


def test_plan_and_preset_event_carry_the_predicted_psnr(tiny_capture, tmp_path):
    settings = json.dumps({"max_size": 48, "coarse_size": 24, "initial_faces": 500})
    env = {"SFT_RECONSTRUCT_SETTINGS": settings}
    proc = run_cli("reconstruct", tiny_capture, "--out", tmp_path / "plan", "--plan", env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    event = json.loads(proc.stdout.strip().splitlines()[-1])
    assert event["probe"]["psnr"] > 0
    gains = forecast.load_gains()
    for name, p in event["presets"].items():
        expected = forecast.predicted_psnr(event["probe"], name, gains)
        assert p["predicted_psnr"] == expected
        if expected is not None:  # "Draft ≈ 2.1 min (≈ 24 ± 3 dB)"
            spread = forecast.gain(gains, name)[1]
            assert f"\u2248 {expected:.0f} \u00b1 {spread:.0f} dB)" in event["line"]
            assert p["psnr_spread"] == spread
    run = tmp_path / "run"
    proc = run_cli("reconstruct", tiny_capture, "--out", run, "--preset", "draft", "--iterations", 4,
                   "--track-accuracy", env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    preset = next(e for e in events if e["event"] == "preset" and e.get("plan"))
    assert preset["probe"]["views"] == 2 and preset["predicted_psnr"] == forecast.predicted_psnr(
        preset["probe"], "draft", gains)
    # the run's own held-out series scores the same views at the same size
    report = json.loads((run / "report.json").read_text())
    assert report["accuracy_time"]["scored_views"] and report["accuracy_time"]["size"] == 48
    assert preset["plan"]["fixed_s"] >= preset["probe"]["seconds"]  # the run's own probe is part of its time


def test_a_failing_probe_leaves_the_run_without_a_prediction():
    """The run goes on without a predicted PSNR, and says why."""
    from backend.errors import InputError
    from backend.planning.job import safe_probe

    def failing(capture, config, held, mesh):
        raise InputError(None, "the visual hull is empty", "check the masks")

    warnings = []
    assert safe_probe(failing, None, None, warn=warnings.append) is None
    assert len(warnings) == 1 and "probe failed" in warnings[0] and "visual hull is empty" in warnings[0]
