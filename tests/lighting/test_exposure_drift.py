"""A phone's auto-exposure simulated (``synth --exposure-drift``, backend.synth.drift): the
drift's model and gauge, the capture it writes (frames times the true gains, the truth, the
flag ``--exposure auto`` reads), the gains renders are scored at, and the panel's row."""

from __future__ import annotations

import json

import numpy as np
import pytest

from addon.io import exposure_report
from backend.capture.images import read_linear_rgb
from backend.capture.load import load_capture
from backend.lighting import exposure
from backend.synth.drift import drift_gains
from tests.helpers import run_cli

VIEWS, SIZE = 6, 16


def test_drift_is_smooth_in_the_gauge_and_its_exposure_swings_by_the_amplitude():
    gains = drift_gains(40, 0.5, 0.2, seed=3)
    stops = np.log2(gains)
    assert np.allclose(stops.mean(0), 0.0, atol=1e-12), "geometric mean 1 per channel: the fit's gauge"
    frame_exposure = stops.mean(1)  # the white-balance terms sum to zero over the channels
    assert 0.49 < np.abs(frame_exposure).max() <= 0.5 + 1e-12
    assert np.abs(stops - frame_exposure[:, None]).max() <= 1.5 * 0.2 + 1e-12
    step = np.abs(np.diff(np.vstack([stops, stops[:1]]), axis=0)).max()
    assert step < 2 * np.pi / 40 * (0.5 + 1.5 * 0.2) + 1e-9, "one slow swing: a small change frame to frame"
    assert np.allclose(drift_gains(40, 0.0, 0.0), 1.0)
    assert not np.allclose(drift_gains(40, 0.5, 0.2, seed=4), gains), "the phases follow the seed"


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    root = tmp_path_factory.mktemp("drift")
    common = ("--views", VIEWS, "--resolution", SIZE, "--spp", 4, "--held-out", 1, "--seed", 2)
    run_cli("synth", "--out", root / "plain", *common, check=True)
    run_cli("synth", "--out", root / "drift", *common, "--exposure-drift", 0.5, "--white-balance-drift", 0.2,
            check=True)
    return root


def test_a_drift_capture_is_the_plain_one_times_its_true_gains(captures):
    plain, drift = load_capture(captures / "plain"), load_capture(captures / "drift")
    truth = json.loads((drift.path(drift.ground_truth["exposure"])).read_text())
    assert truth["exposure_stops"] == 0.5 and list(truth["gains"]) == [f.name for f in drift.frames]
    gains = np.array(list(truth["gains"].values()))
    assert np.allclose(np.log(gains).mean(0), 0.0, atol=1e-5) and np.ptp(np.log2(gains).mean(1)) > 0.5
    for a, b, g in zip(plain.frames, drift.frames, gains):
        assert np.allclose(read_linear_rgb(b.image), read_linear_rgb(a.image) * g, rtol=1e-4, atol=1e-6)
    held = [load_capture(c.path(c.ground_truth["held_out"])).frames[0].image for c in (plain, drift)]
    assert np.allclose(read_linear_rgb(held[0]), read_linear_rgb(held[1]), rtol=1e-4, atol=1e-6), "the truth's views at gain 1"
    assert exposure.enabled("auto", drift) and not exposure.enabled("auto", plain)
    assert "exposure" not in plain.ground_truth


def test_a_drift_out_of_range_is_one_line_and_writes_nothing(tmp_path):
    proc = run_cli("synth", "--out", tmp_path / "bad", "--views", 4, "--resolution", 8, "--exposure-drift", -1)
    assert proc.returncode == 2 and "--exposure-drift is -1" in proc.stderr and "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and not (tmp_path / "bad").exists()


def test_renders_are_scored_at_the_fitted_gains():
    fitted = {"model": "per-frame", "gains": {"a": [0.5, 1.0, 2.0], "b": [1.0, 1.0, 1.0], "c": [2.0, 1.0, 0.5]}}
    gains = exposure.scoring_gains(fitted, ["a", "held"])
    assert np.allclose(gains["a"], [0.5, 1.0, 2.0]), "a fitted frame: its own gains"
    assert np.allclose(gains["held"], [1.0, 1.0, 1.0]), "a held-out frame: the median"
    assert all(np.allclose(g, 1.0) for g in exposure.scoring_gains({"model": "off"}, ["a"]).values())
    assert "median" in exposure.scoring_note(fitted) and "gain 1" in exposure.scoring_note(None)


def test_the_panel_row_gives_the_gains_spread_in_stops(tmp_path):
    gains = drift_gains(12, 0.3, 0.1, seed=0)
    report = {"exposure": {"model": "per-frame", "gains": {f"{i:04d}": g.tolist() for i, g in enumerate(gains)}}}
    (tmp_path / "report.json").write_text(json.dumps(report))
    e, wb = exposure_report.spread(report["exposure"]["gains"])
    stops = np.log2(gains)
    assert e == pytest.approx(np.ptp(stops.mean(1)) / 2) and 0 < wb <= 0.15 + 1e-9
    assert exposure_report.read(tmp_path) == f"Exposure ±{e:.2f} stops, white balance ±{wb:.2f} (12 frames)"
    assert exposure_report.line({"exposure": {"model": "off", "mode": "auto"}}) == ""
    assert exposure_report.read(tmp_path / "missing") == ""
