"""``--lighting auto``: the lighting model chosen by its held-out loss on a short probe.

Real renders of tiny captures whose lights are then stripped from capture.json (as a real
capture comes): one lit by a flash at each camera picks a model fixed to the camera, one lit
by a world-fixed HDR map picks the world map (the summed world + rig maps, which could light
either, win neither: they are ranked with a handicap). End to end, a run without ``--lighting`` on an
unlit capture probes and reports each candidate and the margin; an explicit ``--lighting``
and a capture that records its lights do not probe."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest

from backend import variant

variant.choose()

from backend.capture.load import load_capture  # noqa: E402
from backend.events import read_log  # noqa: E402
from backend.optimize.config import ReconstructConfig  # noqa: E402
from backend.planning import lighting_choice  # noqa: E402
from tests.helpers import REPO, run_cli, shared_data  # noqa: E402
from tests.lighting.test_fitted import ESTIMATE_FAST, ESTIMATE_SETTINGS  # noqa: E402

CAMERA_FIXED = {"flash", "rig"}


def _capture(tmp_path, *lighting):
    """A 10-view 32 px capture rendered under ``lighting`` (synth's options), its lights then
    dropped from capture.json (as a real capture comes)."""
    path = tmp_path / "capture"
    run_cli("synth", "--out", path, *lighting, "--specular", 0, "--views", 10, "--resolution", 32, "--spp", 32,
            "--held-out", 0, check=True)
    data = json.loads((path / "capture.json").read_text())
    data.pop("environment", None)
    for frame in data["frames"]:
        frame.pop("lights", None)
    (path / "capture.json").write_text(json.dumps(data))
    return path


def _choose(path) -> dict:
    events = []
    choice = lighting_choice.choose(load_capture(path), ReconstructConfig(init="carve"),
                                    lambda name, **fields: events.append({"event": name, **fields}))
    assert events[-1]["event"] == lighting_choice.EVENT and events[-1]["winner"] == choice["winner"]
    print(choice["line"], {c["model"]: c["psnr"] for c in choice["candidates"]},  # the figures, for -s logs
          {c["model"]: c["psnr"] for c in choice["runoff"] or []})
    assert {c["model"] for c in choice["candidates"]} == {"estimate", "rig", "world+rig", "flash"}
    if choice["runoff"] is not None:  # a near tie: the first two fitted longer decide
        assert len(choice["runoff"]) == 2 and choice["winner"] in {c["model"] for c in choice["runoff"]}
        assert choice["line"].endswith("(run-off)")
    assert all(c["loss"] > 0 and c["cycles"] >= 1 for c in choice["candidates"])
    assert choice["margin_db"] > 0 and len(choice["held_out"]) == lighting_choice.HELD_OUT
    return choice


def test_a_flash_lit_capture_picks_a_camera_fixed_model(tmp_path):
    choice = _choose(_capture(tmp_path, "--lighting", "flash", "--light-intensity", 2.0))
    assert choice["winner"] in CAMERA_FIXED, choice
    world = next(c for c in choice["candidates"] if c["model"] == "estimate")
    best = next(c for c in choice["candidates"] if c["model"] == choice["winner"])
    assert best["psnr"] > world["psnr"] + 1, choice


def test_a_map_lit_capture_picks_the_world_map(tmp_path):
    choice = _choose(_capture(tmp_path, "--lighting", "env", "--env", shared_data("envmaps", "forest_slope_1k.hdr")))
    assert choice["winner"] == "estimate", choice


def test_a_near_tie_after_the_first_level_keeps_the_provisional_lighting():
    later = lighting_choice.Deferred(ReconstructConfig(), ["estimate", "rig", "world+rig", "flash"], None)

    def choice(winner, losses, runoff=None):
        rows = lambda d: [{"model": m, "loss": x} for m, x in d.items()]  # noqa: E731
        return {"winner": winner, "runner_up": None, "margin_db": 1.0, "candidates": rows(losses),
                "runoff": rows(runoff) if runoff else None, "probed_on": "level 0 mesh", "line": ""}

    near = later.settle(choice("estimate", {"estimate": 0.040, "world+rig": 0.042, "rig": 0.05},
                               runoff={"estimate": 0.035, "world+rig": 0.037}))
    assert near["kept"] and near["winner"] == lighting_choice.PROVISIONAL and near["runner_up"] == "estimate"
    assert near["margin_db"] == pytest.approx(-10 * math.log10(0.037 / 0.035), abs=1e-3)  # the run-off's gap
    far = later.settle(choice("flash", {"flash": 0.010, "world+rig": 0.030, "estimate": 0.040}))
    assert not far["kept"] and far["winner"] == "flash"
    own = later.settle(choice("world+rig", {"world+rig": 0.030, "estimate": 0.031}))
    assert not own["kept"] and own["winner"] == "world+rig"


def test_held_out_frames_are_spread_and_distinct():
    for n in (6, 7, 10, 49):
        ids = lighting_choice.held_out(n)
        assert len(ids) == lighting_choice.HELD_OUT and all(0 < i < n - 1 for i in ids), (n, ids)
        assert ids[1] - ids[0] >= n // 2 - 1


@pytest.mark.parametrize("explicit", [False, True])
def test_reconstruct_probes_only_without_an_explicit_lighting(tmp_path, explicit):
    path = _capture(tmp_path, "--lighting", "flash", "--light-intensity", 2.0)
    run = tmp_path / "run"
    settings = {**ESTIMATE_SETTINGS, "level_iterations": 5, "min_level_iterations": 2, "time_budget_s": 20}
    proc = run_cli("reconstruct", path, "--out", run, *(["--lighting", "flash"] if explicit else []),
                   *ESTIMATE_FAST, timeout=400, env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(settings)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads((run / "report.json").read_text())
    events = [e for e in read_log(run / "events.jsonl") if e.get("event") == lighting_choice.EVENT]
    if explicit:
        assert "lighting_choice" not in report and not events
        return
    choice = report["lighting_choice"]
    start = next(e for e in read_log(run / "events.jsonl") if e.get("event") == "start")
    assert start["settings"]["lighting"] == "auto"  # the default for a capture without light
    assert len(events) == 1 and events[0]["winner"] == choice["winner"]
    assert len(choice["candidates"]) == 4 and (choice["margin_db"] > 0 or choice["kept"])
    assert choice["line"].startswith("lighting: ")
    assert report["settings"]["lighting"] == choice["winner"]
    model = report["lighting"]["model"]
    assert model == ("flash" if choice["winner"] == "flash" else "environment map (estimated)")
    _chosen_after_the_first_level(read_log(run / "events.jsonl"), choice)


def _chosen_after_the_first_level(log: list[dict], choice: dict) -> None:
    """The choice was made on the first level's mesh, under the provisional lighting, after that
    level's geometry steps and before any of the next level's."""
    assert choice["probed_on"].startswith("level 0 mesh") and choice["provisional"] == lighting_choice.PROVISIONAL
    assert choice["line"].endswith("on the " + choice["probed_on"])
    kinds = [(e["event"], e.get("stage"), e.get("level")) for e in log]
    at = [k[0] for k in kinds].index(lighting_choice.EVENT)
    probe = kinds.index(("stage", "lighting:probe", 0))
    levels = [(i, k[2]) for i, k in enumerate(kinds) if k[:2] == ("stage", "geometry")]  # each level's start
    assert levels and levels[0][1] == 0 and levels[0][0] < probe < at, "the probe did not follow the first level"
    assert all(level == 0 for i, level in levels if i < at)


def test_a_run_stopped_after_the_choice_resumes_under_the_winner(tmp_path):
    """--resume of an auto run stopped after its choice: no second probe, the winner's lighting
    comes back from the folder (a flash from the state, a map from its files)."""
    path = _capture(tmp_path, "--lighting", "flash", "--light-intensity", 2.0)
    run = tmp_path / "run"
    settings = {**ESTIMATE_SETTINGS, "level_iterations": 6, "min_level_iterations": 3, "max_levels": 2,
                "time_budget_s": 60}
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1", SFT_RECONSTRUCT_SETTINGS=json.dumps(settings))
    proc = subprocess.Popen([sys.executable, "-m", "backend", "reconstruct", str(path), "--out", str(run),
                             *ESTIMATE_FAST], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=REPO)
    for line in proc.stdout:
        if json.loads(line)["event"] == lighting_choice.EVENT:
            (run / "STOP").touch()
            break
    proc.communicate(timeout=300)
    assert proc.returncode == 130, "the run did not stop after its choice"
    first = [e for e in read_log(run / "events.jsonl") if e.get("event") == lighting_choice.EVENT]
    assert len(first) == 1
    resumed = run_cli("reconstruct", path, "--out", run, "--resume", *ESTIMATE_FAST, timeout=400,
                      env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(settings)})
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    log = read_log(run / "events.jsonl")
    later = log[[e["event"] for e in log].index("start", 1):]
    assert not any(e.get("stage") == "lighting:probe" for e in later)  # the recorded choice is kept
    report = json.loads((run / "report.json").read_text())
    winner = first[0]["winner"]
    assert report["lighting_choice"]["winner"] == winner and report["settings"]["lighting"] == winner
    assert report["lighting"]["model"] == ("flash" if winner == "flash" else "environment map (estimated)")
