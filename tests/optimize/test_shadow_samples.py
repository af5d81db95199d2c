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
    assert s.next_count() == 5 and not s.record(5, 2.0)  # settled: the new count compiles, untimed
    record = s.to_json()
    assert record["chosen"] == 5 and record["measured_ratio"] == 3.0 and record["expected_ratio"] <= RATIO
    assert record["achieved_ratio"] is None and not record["checked"]


def test_the_kept_count_is_checked_on_its_own_steps():
    """Where the line held, the check only measures; later steps keep the count."""
    s = ShadowSamples(12)
    for n in (12, 0, 12, 0, 12, 0, 12, 0):  # two compiles, then 3x at 12 samples, 1 s without
        s.record(n, 3.0 if n else 1.0)
    assert s.chosen == 5
    s.record(5, 9.0)  # the new count's compile: not timed
    assert [s.record(5, t) for t in (1.80, 1.85, 1.82)] == [False, False, True]
    assert s.checked and s.chosen == 5 and not s.corrections
    assert s.achieved_ratio == pytest.approx(1.82)
    assert not s.record(5, 1.9)  # checked once; the level's later steps still count
    assert s.to_json()["kept_steps"] == 4 and s.to_json()["achieved_ratio"] == pytest.approx(1.835, abs=1e-3)


def test_a_count_costlier_than_its_line_is_cut_once():
    """Samples cost more than the line from the full count said (2.4x achieved at 5 samples):
    the count is derived again from the line through its own steps, once."""
    s = ShadowSamples(12)
    for n in (12, 0, 12, 0, 12, 0, 12, 0):
        s.record(n, 3.0 if n else 1.0)
    s.record(5, 9.0)
    assert [s.record(5, 2.4) for _ in range(3)] == [False, False, True]
    # floor(5 * 0.9 / 1.4) = 3, held at the floor of 4
    assert s.chosen == 4 and s.corrections == [{"chosen": 5, "achieved_ratio": 2.4}]
    assert s.expected_ratio() == pytest.approx(1 + 1.4 * 4 / 5)
    s.record(4, 9.0)  # compile
    assert [s.record(4, 2.3) for _ in range(3)] == [False, False, True]
    assert s.chosen == 4 and len(s.corrections) == 1  # at the floor: measured, not cut again
    assert s.to_json()["achieved_ratio"] == pytest.approx(2.3)


def test_a_correction_above_the_floor():
    s = ShadowSamples(24)
    for n in (24, 0, 24, 0, 24, 0, 24, 0):
        s.record(n, 2.5 if n else 1.0)
    assert s.chosen == 14  # floor(24 * 0.9 / 1.5)
    s.record(14, 9.0)
    for _ in range(3):
        s.record(14, 2.8)  # 1.8 per 14 samples, not the 0.875 the line from 24 said
    assert s.chosen == 7 and s.corrections[0]["chosen"] == 14  # floor(14 * 0.9 / 1.8)
    s.record(7, 9.0)
    for _ in range(3):
        s.record(7, 2.2)  # still above the ratio: one correction only, then it is measured
    assert s.chosen == 7 and s.checked and s.achieved_ratio == pytest.approx(2.2)


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
    samples = [e for e in events if e["event"] == "shadow_samples"]
    assert samples, "no level settled its shadow samples"
    last = {}  # a level reports when it settles its count and again when it has checked it
    for e in samples:
        assert 4 <= e["chosen"] <= e["full"] == 12
        assert e["step_seconds"] > 0 and e["base_seconds"] > 0
        assert e["expected_ratio"] <= RATIO or e["chosen"] == 4
        last[(e["stage"], e["level"])] = e
    assert any(e["checked"] and e["achieved_ratio"] > 0 for e in samples), "no level checked its count"
    levels = json.loads((run / "report.json").read_text())["levels"]
    recorded = [lv["shadow_samples"] for lv in levels if lv.get("shadow_samples")]
    assert [r["chosen"] for r in recorded] == [e["chosen"] for e in last.values()]
    for r in recorded:  # the level's record: what the kept count cost over all its steps
        if r["kept_steps"]:
            assert r["achieved_ratio"] > 0 and r["kept_seconds"] > 0
