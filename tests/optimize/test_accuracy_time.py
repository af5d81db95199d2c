"""--track-accuracy: held-out PSNR against run time (backend/planning/tracking.py), its events,
report.json ``accuracy_time``, RUN/accuracy_time.png and the next-level estimate."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from backend.optimize.config import ReconstructConfig
from tests.helpers import REPO, run_cli

TINY = ["--max-size", "32", "--coarse-size", "16", "--initial-faces", "800", "--spp", "4", "--init", "sphere",
        "--effects", "specular", "--remesh", "never"]
SETTINGS = json.dumps({"accuracy_every_s": 1, "validation_views": 2})


def synth(out: Path, held_out: int) -> Path:
    run_cli("synth", "--out", out, "--views", 16, "--resolution", 32, "--spp", 32, "--held-out", held_out,
            "--albedo", "0.6,0.6,0.6", check=True)
    return out


@pytest.fixture(scope="module")
def truth_capture(tmp_path_factory) -> Path:
    """16 views and 2 ground-truth held-out views (gt/held_out)."""
    return synth(tmp_path_factory.mktemp("truth") / "capture", 2)


@pytest.fixture(scope="module")
def plain_capture(tmp_path_factory) -> Path:
    """16 views, no ground-truth held-out views: every 8th view is held out."""
    return synth(tmp_path_factory.mktemp("plain") / "capture", 0)


def test_a_tracked_run_draws_held_out_psnr_rising_with_time(truth_capture, tmp_path):
    run = tmp_path / "run"
    proc = run_cli("reconstruct", truth_capture, "--out", run, *TINY, "--material", "staged", "--iterations", 80,
                   "--level-iterations", 40, "--max-levels", 2, "--track-accuracy",
                   env={"SFT_RECONSTRUCT_SETTINGS": SETTINGS}, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = [json.loads(line) for line in proc.stdout.splitlines()]
    report = json.loads((run / "report.json").read_text())
    series = report["accuracy_time"]
    # the synthetic capture's own held-out views are scored: every view is fitted
    assert series["source"] == "ground truth" and series["fitted_views"] == 16
    assert series["held_out_views"] == series["scored_views"] == ["held00", "held01"]
    points = series["points"]
    events = [{k: v for k, v in e.items() if k not in ("event", "time")} for e in log if e["event"] == "accuracy"]
    assert events == points and len(points) >= 6
    seconds = [p["seconds"] for p in points]
    assert np.all(np.diff(seconds) >= 0), seconds
    assert all(math.isfinite(p["psnr"]) for p in points)
    assert all(p["validation_loss"] > 0 for p in points[1:])  # the first score precedes any validation
    assert points[-1]["psnr"] > points[0]["psnr"] + 2, [p["psnr"] for p in points]  # accuracy rises with time
    assert points[0]["why"] == "start" and points[-1]["why"] == "end"
    # level and stage boundaries
    marks = series["marks"]
    assert [m["level"] for m in marks if m["stage"] == "geometry"] == [0, 1]
    assert any(m["stage"].startswith("material:") for m in marks)
    assert [g["level"] for g in series["level_gains"]] == [0, 1]
    assert report["timings"]["accuracy"] > 0 and series["scoring_seconds"] > 0
    assert report["levels_ended"] == "iterations" and report["next_level"] is None
    assert log[-1]["event"] == "done" and log[-1]["next_level"] is None
    with Image.open(run / series["figure"]) as image:
        assert image.format == "PNG" and image.size == (560, 300)
        pixels = np.asarray(image.convert("RGB")).reshape(-1, 3)
    from backend.planning import tracking_figure as figure

    for colour in (figure.PSNR_COLOUR, figure.STAGE_COLOURS["geometry"], figure.STAGE_COLOURS["material"]):
        assert (pixels == colour).all(-1).sum() > 20, colour


def test_without_ground_truth_every_8th_view_is_held_out_and_never_fitted(plain_capture, tmp_path):
    from backend import variant

    variant.choose(None)
    from backend.capture.load import load_capture
    from backend.optimize.objective import Objective
    from backend.optimize.run import reconstruct
    from backend.optimize.run_folder import RunFolder
    from backend.planning import tracking

    fitted: set[str] = set()

    def recording(mesh, material, views, *args, **kwargs):
        fitted.update(v.name for v in views)
        return Objective(mesh, material, views, *args, **kwargs)

    capture = load_capture(plain_capture)
    names = [f.name for f in capture.frames]
    config = ReconstructConfig(init="sphere", material="known:0.6,0.6,0.6:0.25:0.35", effects="specular",
                               max_size=32, coarse_size=32, initial_faces=800, spp=4, max_levels=1, iterations=30,
                               level_iterations=30, validation_views=2, track_accuracy=True, accuracy_every_s=1)
    folder = RunFolder.create(tmp_path / "run", resume=False, overwrite=False)
    assert reconstruct(capture, folder, config, lambda *a, **k: None, objective_factory=recording,
                       tracking=tracking.start).exit_code == 0
    series = json.loads((tmp_path / "run" / "report.json").read_text())["accuracy_time"]
    held = [names[4], names[12]]  # material.stages.check_views(16, 8)
    assert series["source"] == "every 8th view" and series["held_out_views"] == held and series["fitted_views"] == 14
    assert fitted == set(names) - set(held)
    assert len(series["points"]) >= 3 and (tmp_path / "run" / "accuracy_time.png").is_file()


def test_the_score_follows_the_material_and_too_few_views_are_not_held_out(plain_capture):
    from backend import variant

    variant.choose(None)
    from backend.capture.load import load_capture
    from backend.geometry.mesh import load_mesh
    from backend.material import factory
    from backend.planning import tracking as accuracy

    capture = load_capture(plain_capture)
    config = ReconstructConfig(track_accuracy=True, max_size=32)
    _, held = accuracy.split(capture, config)
    tracker = accuracy.AccuracyTracker(held, config)
    truth = load_mesh(capture.path(capture.ground_truth["mesh"]))

    def score(material: str, folder: Path) -> float:
        return tracker.score(truth, factory.create(material), level=0, phase="level", why="every",
                             validation_loss=None, folder=folder)["psnr"]

    folder = Path(capture.root).parent / "scores"
    right, dark = score("known:0.6,0.6,0.6:0.25:0.35", folder), score("known:0.1,0.1,0.1:0.25:0.35", folder)
    assert right > dark + 5 and right > 25, (right, dark)
    assert (folder / accuracy.FIGURE).is_file()
    few = dataclasses.replace(capture, frames=capture.frames[:12])
    same, nothing = accuracy.split(few, ReconstructConfig(track_accuracy=True))
    assert same is few and nothing.capture is None and "too few" in nothing.note
    off, none = accuracy.split(capture, ReconstructConfig())
    assert off is capture and none.capture is None and none.note is None  # not asked for: nothing changes
    # point lights: the configured samples; an environment map lights from every direction: more
    assert tracker.spp == config.accuracy_spp == tracker.spp_for(None)
    assert tracker.spp_for(object()) == accuracy.ENV_SPP_FACTOR * config.accuracy_spp


def test_a_time_budget_says_what_the_next_level_was_expected_to_buy():
    from backend.optimize.convergence import next_level
    from backend.optimize.records import LevelRecord

    levels = [LevelRecord(level=k, size=s, faces=100, iterations=40, loss_start=0.02, loss=0.015, step_final=1.0,
                          material_frozen_at=None, seconds=30.0, elapsed=30.0 * (k + 1))
              for k, s in ((0, 64), (1, 128))]
    gains = [{"level": 0, "psnr": 20.0, "psnr_gain_db": 3.0, "seconds": 35.0},
             {"level": 1, "psnr": 21.2, "psnr_gain_db": 1.2, "seconds": 40.0}]
    estimate = next_level(levels, "time budget", gains, 256)
    assert estimate["level"] == 2 and estimate["size"] == 256 and estimate["extrapolated"]
    assert estimate["psnr_gain_db"] == 1.2 and estimate["validation_loss_drop"] == 0.25
    assert "+1.20 dB" in estimate["line"] and "extrapolated" in estimate["line"]
    untracked = next_level(levels, "time budget", [], 256)
    assert untracked["psnr_gain_db"] is None and "25.0 % lower validation loss" in untracked["line"]
    assert next_level(levels, "converged", gains, 256) is None


def test_a_resumed_run_continues_its_series(plain_capture, tmp_path):
    run = tmp_path / "run"
    options = [*TINY, "--material", "known:0.6,0.6,0.6:0.25:0.35", "--iterations", 150, "--max-levels", 1,
               "--track-accuracy"]
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1", SFT_RECONSTRUCT_SETTINGS=SETTINGS)
    proc = subprocess.Popen([sys.executable, "-m", "backend", "reconstruct", str(plain_capture), "--out", str(run),
                             *map(str, options)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, cwd=REPO)
    scores = 0
    for line in proc.stdout:
        scores += json.loads(line)["event"] == "accuracy"
        if scores == 3:
            (run / "STOP").touch()
            break
    proc.communicate(timeout=120)
    assert proc.returncode == 130
    before = json.loads((run / "state" / "state.json").read_text())["accuracy"]["points"]
    assert len(before) >= 3
    resumed = run_cli("reconstruct", plain_capture, "--out", run, *options, "--resume",
                      env={"SFT_RECONSTRUCT_SETTINGS": SETTINGS}, timeout=300)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    series = json.loads((run / "report.json").read_text())["accuracy_time"]
    points = series["points"]
    assert points[:len(before)] == before and points[len(before)]["why"] == "resume"
    assert np.all(np.diff([p["seconds"] for p in points]) >= 0)
    assert [m["stage"] for m in series["marks"]].count("resume") == 1
    assert series["fitted_views"] == 14  # the same views held out as before the stop
