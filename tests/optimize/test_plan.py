"""The plan (planning/time_plan.py): the cost model's pieces, then ``reconstruct --plan`` and the
``preset`` event on a tiny synthetic capture (6 views at 32 px, real step timings)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from backend.planning import time_plan as plan
from backend.optimize.config import ReconstructConfig
from backend.planning.presets import PRESETS, calibrated
from tests.helpers import run_cli


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plan") / "capture"
    run_cli("synth", "--out", out, "--views", 6, "--resolution", 32, "--spp", 16, "--held-out", 0, check=True)
    return out


def test_fit_recovers_a_plane_and_drops_negative_terms():
    samples = [(p, f, 0.01 + 2e-6 * p + 3e-7 * f) for p in (1000, 9000) for f in (1000, 20000)]
    a, b, c = plan.fit(samples)
    assert a == pytest.approx(0.01) and b == pytest.approx(2e-6) and c == pytest.approx(3e-7)
    # a face count that makes steps cheaper is noise: dropped, never negative
    a, b, c = plan.fit([(1000, 1000, 0.2), (1000, 20000, 0.1), (9000, 1000, 0.5)])
    assert min(a, b, c) >= 0
    assert plan.fit([(1000, 500, 0.3), (1000, 500, 0.5)]) == pytest.approx((0.4, 0.0, 0.0))


def test_levels_follow_the_face_budget_and_the_calibration_steps():
    draft = ReconstructConfig(**PRESETS["draft"])
    levels, source = plan.levels(draft)
    assert [lv.size for lv in levels] == [48, 96, 96]
    assert [lv.faces for lv in levels] == [2000, 4000, 5000]  # x4 capped at D = 4000, then D + 1000
    assert all(lv.steps == draft.level_iterations for lv in levels) and source.startswith("config")
    final = ReconstructConfig(**PRESETS["final"])
    levels, source = plan.levels(final, {"levels": 8, "iterations": 1370})
    assert len(levels) == 8 and {lv.steps for lv in levels} == {171} and source.startswith("calibration")
    capped = ReconstructConfig(**PRESETS["final"], iterations=500)
    assert sum(lv.steps for lv in plan.levels(capped, {"levels": 8, "iterations": 1370})[0]) == 500


def test_a_calibrated_plan_ends_each_level_a_little_after_its_steps():
    balanced = ReconstructConfig(**PRESETS["balanced"])
    assert plan.level_limit(balanced, {"levels": 6, "iterations": 1188}) == 248  # 1.25 x 198
    assert plan.level_limit(balanced, {"levels": 6, "iterations": 2400}) == balanced.level_iterations
    assert plan.level_limit(balanced, {"levels": 6, "iterations": 60}) == balanced.min_level_iterations
    assert plan.level_limit(balanced, None) is None  # no calibration: the config's own cap
    costs = plan.StepCosts([], {kind: (0.01, 0.0, 0.0) for kind in ("gradient", "forward", "material")})
    planned = plan.predict("balanced", balanced, costs, lambda size: size * size, 32, True,
                           {"levels": 6, "iterations": 1188})
    assert planned.level_limit == 248 and planned.to_json()["level_limit"] == 248
    assert {p.cap for p in planned.phases if p.kind == "level"} == {248}


def test_plan_prints_one_row_per_preset_and_runs_nothing(capture, tmp_path):
    run = tmp_path / "run"
    proc = run_cli("reconstruct", capture, "--out", run, "--plan", timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = proc.stdout.strip().splitlines()
    rows = {line.split()[0]: line.split() for line in lines[1:] if line.split()[0] in PRESETS}
    assert list(rows) == list(PRESETS)  # draft, balanced, final
    minutes = [float(rows[name][5]) for name in PRESETS]
    assert 0 < minutes[0] < minutes[1] < minutes[2], lines
    summary = next(line for line in lines if line.startswith("Draft \u2248"))
    assert "Balanced \u2248" in summary and "on this capture" in summary
    event = json.loads(lines[-1])  # the same as one event, for the add-on
    assert event["event"] == "plan" and event["line"] in summary
    assert [event["presets"][n]["predicted_minutes"] for n in PRESETS] == pytest.approx(minutes, abs=0.06)
    assert not run.exists()


def test_the_preset_event_carries_the_captures_prediction(capture, tmp_path):
    run = tmp_path / "run"
    proc = run_cli("reconstruct", capture, "--out", run, "--preset", "draft", "--init", "sphere",
                   "--iterations", 6, "--max-size", 16, "--coarse-size", 16, "--initial-faces", 320,
                   "--material", "known:0.6,0.6,0.6:0.25:0.35", "--effects", "specular", timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    preset = next(e for e in events if e["event"] == "preset" and e.get("plan"))
    assert preset["preset"] == "draft" and preset["predicted_minutes"] > 0
    assert preset["expected_minutes"] is not None  # the calibration's figure stays (point-lit capture)
    assert sum(lv["steps"] for lv in preset["plan"]["levels"]) == 6  # the iteration cap
    assert preset["plan"]["costs"]["seconds"] < 30 and preset["plan"]["costs"]["points"]
    # the preset is announced before the first step; the plan, with the effects the run decided,
    # once the first level has ended, so that measuring the steps does not delay the first one
    order = [e["event"] for e in events]
    first_step = next(i for i, e in enumerate(events) if e["event"] == "stage" and e.get("stage") == "geometry")
    assert order.index("preset") < first_step < events.index(preset)
    assert order.index("effects") < events.index(preset)
    decided = next(e for e in events if e["event"] == "effects")["enabled"]
    timed = preset["plan"]["render_settings"]
    assert timed["max_depth"] == decided["max_depth"] and (timed["sppi"] > 0) == decided["shadows"]


def test_a_budgeted_run_plans_only_from_cached_costs(capture, tmp_path):
    """A time budget bounds the run whatever the plan says: it measures no step costs of its own."""
    fresh = tmp_path / "capture"
    shutil.copytree(capture, fresh, ignore=shutil.ignore_patterns(".sft-cache"))
    run = tmp_path / "run"
    proc = run_cli("reconstruct", fresh, "--out", run, "--preset", "draft", "--init", "sphere", "--time-budget", 20,
                   "--iterations", 6, "--max-size", 16, "--coarse-size", 16, "--initial-faces", 320,
                   "--material", "known:0.6,0.6,0.6:0.25:0.35", "--effects", "specular", timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    presets = [e for e in events if e["event"] == "preset"]
    assert presets and not any(e.get("plan") for e in presets)
    assert not (fresh / ".sft-cache" / "step_costs.json").exists()
    report = json.loads((run / "report.json").read_text())
    assert report["timings"].get("plan", 0.0) < 1.0


def test_a_fitted_lighting_is_charged_its_cycles_on_the_initial_mesh():
    """``--lighting estimate``/``flash`` fit the light first (config.light_first_cycles constant-
    material cycles at level 0's size and faces): the plan adds exactly those cycles."""
    costs = plan.StepCosts([plan.Point(32, 1024, 500, 0.02, 0.01, 0.015), plan.Point(64, 4096, 500, 0.05, 0.02, 0.03),
                            plan.Point(32, 1024, 4000, 0.03, 0.012, 0.02), plan.Point(64, 4096, 4000, 0.07, 0.03, 0.04)])
    pixels_at = lambda size: size * size  # noqa: E731
    captured = ReconstructConfig(**PRESETS["draft"], material="staged")
    estimated = ReconstructConfig(**PRESETS["draft"], material="staged", lighting="estimate")
    a = plan.predict("draft", captured, costs, pixels_at, 8, staged=True)
    b = plan.predict("draft", estimated, costs, pixels_at, 8, staged=True)
    first = a.levels[0]
    expected = estimated.light_first_cycles * plan.cycle_seconds(costs, pixels_at(first.size), first.faces, 8)
    assert b.material_s - a.material_s == pytest.approx(expected) and expected > 0
    assert b.geometry_s == pytest.approx(a.geometry_s)
    # several materials under the captured lights fit their constants first as well
    several = ReconstructConfig(**PRESETS["draft"], material="staged", n_materials=3)
    c = plan.predict("draft", several, costs, pixels_at, 8, staged=True)
    assert c.material_s - a.material_s == pytest.approx(expected)


def test_the_final_material_cycles_and_the_polish_are_charged_as_configured():
    """``final_material_cycles`` caps the long cycles on the converged surface the plan charges
    (``FINAL_MATERIAL_CYCLES`` otherwise), and ``polish_rounds`` 0 charges no polish (Draft)."""
    costs = plan.StepCosts([plan.Point(32, 1024, 500, 0.02, 0.01, 0.015), plan.Point(64, 4096, 500, 0.05, 0.02, 0.03),
                            plan.Point(32, 1024, 4000, 0.03, 0.012, 0.02), plan.Point(64, 4096, 4000, 0.07, 0.03, 0.04)])
    pixels_at = lambda size: size * size  # noqa: E731
    base = {**PRESETS["draft"], "material": "staged"}
    full = plan.predict("draft", ReconstructConfig(**{**base, "final_material_cycles": 12}), costs, pixels_at, 8, staged=True)
    one = plan.predict("draft", ReconstructConfig(**{**base, "final_material_cycles": 1}), costs, pixels_at, 8, staged=True)
    long_cycle = plan.cycle_seconds(costs, pixels_at(base["max_size"]), full.levels[-1].faces, 8, scale=4)
    assert full.material_s - one.material_s == pytest.approx((plan.FINAL_MATERIAL_CYCLES - 1) * long_cycle)
    assert PRESETS["draft"]["polish_rounds"] == 0 and one.polish_s == 0 and full.geometry_s == pytest.approx(one.geometry_s)


def test_shadow_gradients_are_charged_at_the_samples_a_level_keeps(tmp_path):
    """Under an environment map with shadow gradients the plan times the geometry step with and
    without them and charges the count a level keeps (the arithmetic: test_shadow_samples.py)."""
    from backend import variant

    variant.choose()
    from backend.capture.load import load_capture
    from backend.optimize.views import ViewSet
    from backend.render.scene import RenderSettings

    out = tmp_path / "capture"
    run_cli("synth", "--out", out, "--views", 4, "--resolution", 32, "--spp", 16, "--held-out", 0,
            "--lighting", "env", "--env", "sky", check=True)
    capture = load_capture(out)
    viewset = ViewSet(capture, 32)
    shadows = RenderSettings(spp=4, max_depth=3, integrator="prb_projective", sppc=4, sppp=4, sppi=12)
    costs = plan.measure(capture, viewset, shadows, [32], [320], repeats=3)
    (point,) = costs.points
    assert point.gradient > 0 and point.forward > 0 and point.material > 0
    assert costs.coefficients["gradient"][0] + costs.coefficients["gradient"][1] * point.pixels > 0


def test_a_capture_is_promised_the_figures_of_its_kind_of_lighting(tmp_path):
    """Point lights or a flash: the dragon's; an environment map, given or estimated: the
    HDR-lit scene's; a file without kinds (older format): the top level for point lights only."""
    from types import SimpleNamespace

    from backend.planning.presets import calibrated, calibration_scene, lighting_kind

    lit = SimpleNamespace(environment=object())
    dark = SimpleNamespace(environment=None)
    assert lighting_kind(lit) == "environment" and lighting_kind(dark) == "point"
    assert lighting_kind(dark, "estimate") == "environment" and lighting_kind(dark, "flash") == "point"
    entry = {"expected_minutes": 2.0, "expected_f1": 0.9}
    path = tmp_path / "presets.json"
    path.write_text(json.dumps({"scene": "dragon: x", "presets": {"draft": entry},
                                "kinds": {"point": {"scene": "dragon: x", "presets": {"draft": entry}},
                                          "environment": {"scene": "blob_env: y",
                                                          "presets": {"draft": {**entry, "expected_f1": 0.8}}}}}))
    assert calibrated(path, kind="environment")["draft"]["expected_f1"] == 0.8
    assert calibrated(path)["draft"]["expected_f1"] == 0.9 and calibration_scene("environment", path) == "blob_env: y"
    path.write_text(json.dumps({"scene": "dragon: x", "presets": {"draft": entry}}))
    assert calibrated(path, kind="environment") == {} and calibration_scene("environment", path) is None
    assert calibrated(path)["draft"] == entry


def test_a_run_ends_each_level_at_its_plans_limit(capture, tmp_path):
    """A level whose validation loss never stops improving (here: any loss counts as a new
    best) ends at 1.25x the calibrated steps per level, not at ``--level-iterations``."""
    run = tmp_path / "run"
    proc = run_cli("reconstruct", capture, "--out", run, "--preset", "draft", "--init", "sphere",
                   "--level-iterations", 1000, "--max-levels", 1, "--max-size", 16, "--coarse-size", 16,
                   "--initial-faces", 320, "--material", "known:0.6,0.6,0.6:0.25:0.35", "--effects", "specular",
                   env={"SFT_RECONSTRUCT_SETTINGS": json.dumps({"plateau_tolerance": -1.0, "polish_rounds": 0})},
                   timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    preset = next(e for e in events if e["event"] == "preset" and e.get("plan"))
    limit = preset["plan"]["level_limit"]
    entry = calibrated(kind=preset["lighting_kind"])["draft"]
    assert limit == plan.level_limit(ReconstructConfig(**{**PRESETS["draft"], "level_iterations": 1000}), entry)
    report = json.loads((run / "report.json").read_text())
    assert report["level_limit"] == limit < 1000
    assert [lv["iterations"] for lv in report["levels"] if not lv.get("polish")] == [limit]
