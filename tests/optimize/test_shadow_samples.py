"""Each level affords as many shadow-gradient samples as keep its step within 2x of one
without them, timed on its own steps."""

import json

import pytest

from backend.optimize.shadow_samples import RATIO, ShadowSamples, charged_seconds, count_for_ratio
from tests.helpers import run_cli


@pytest.mark.parametrize("measured, expected", [(1.3, 12), (1.9, 12), (2.8, 6), (2.39, 7), (20.0, 4)])
def test_count_keeps_a_linear_cost_within_the_ratio(measured, expected):
    n = count_for_ratio(12, measured, ratio=1.9, minimum=4)
    assert n == expected
    if n > 4:  # above the floor the linear model puts the step at or under the ratio
        assert 1 + (measured - 1) * n / 12 <= 1.9 + 1e-9


def test_a_plan_charges_the_step_at_the_count_kept():
    assert charged_seconds(1.5, 1.0, 12) == 1.5  # within the ratio: all 12 samples, as timed
    # 3x at 12 samples: 5 kept, 1 + 2 * 5 / 12 s
    assert charged_seconds(3.0, 1.0, 12) == pytest.approx(1 + 2 * 5 / 12)
    assert charged_seconds(3.0, 1.0, 12) <= RATIO * 1.0
    assert charged_seconds(40.0, 1.0, 12) == pytest.approx(1 + 39 * 4 / 12)  # the floor of 4 samples


def test_schedule_alternates_untimed_compiles_then_settles():
    s = ShadowSamples(12)
    counts = []
    for step in range(12):
        n = s.next_count()
        counts.append(n)
        # a step with the shadow term costs 3 s, without it 1 s; the first two (compiles) 10 s
        done = s.record(n, 10.0 if step < 2 else (3.0 if n else 1.0))
        if done:
            break
    assert counts == [12, 0, 12, 0, 12, 0, 12, 0]
    assert s.measured_ratio == pytest.approx(3.0)
    assert s.chosen == count_for_ratio(12, 3.0) == 5
    assert s.next_count() == 5 and not s.record(5, 2.0)  # settled: later steps keep the count
    record = s.to_json()
    assert record["chosen"] == 5 and record["measured_ratio"] == 3.0 and record["expected_ratio"] <= RATIO


def test_no_shadow_gradients_no_schedule():
    s = ShadowSamples(0)
    assert not s.active and s.next_count() == 0 and not s.record(0, 1.0)


def test_reconstruct_reports_the_samples_each_level_afforded(tmp_path):
    """A real env-lit run with shadow gradients forced on: every level times its steps, keeps a
    count within [min, full] and says so in an event and in report.json."""
    capture = tmp_path / "capture"
    run_cli("synth", "--out", capture, "--views", 6, "--resolution", 32, "--spp", 32, "--held-out", 0,
            "--lighting", "env", "--env", "sky", check=True)
    run = tmp_path / "run"
    proc = run_cli("reconstruct", capture, "--out", run, "--init", "sphere", "--iterations", 60,
                   "--level-iterations", 30, "--max-size", "32", "--coarse-size", "16", "--initial-faces", "800",
                   "--spp", "4", "--material", "known:0.6,0.6,0.6:0.25:0.35", "--effects", "shadows,silhouettes",
                   timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    events = [json.loads(line) for line in proc.stdout.splitlines()]
    effects = [e for e in events if e["event"] == "effects"]
    assert effects and effects[0]["enabled"]["shadows"]
    chosen = [e for e in events if e["event"] == "shadow_samples"]
    assert chosen, "no level settled its shadow samples"
    for e in chosen:
        assert 4 <= e["chosen"] <= e["full"] == 12
        assert e["step_seconds"] > 0 and e["base_seconds"] > 0
        assert e["expected_ratio"] <= RATIO or e["chosen"] == 4
    levels = json.loads((run / "report.json").read_text())["levels"]
    assert [lv["shadow_samples"]["chosen"] for lv in levels if "shadow_samples" in lv] == [e["chosen"] for e in chosen]
