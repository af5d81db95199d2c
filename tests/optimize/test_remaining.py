"""The time left (planning/remaining.py): the plan's phases, a run replayed through them at
the planned pace, a slower one, a budget; then a real staged run's progress events."""

from __future__ import annotations

import json

import pytest

from backend.planning import time_plan as plan
from backend.optimize.config import ReconstructConfig
from backend.planning.presets import PRESETS
from backend.planning.remaining import END_S, Phase, Remaining
from tests.helpers import run_cli

COSTS = plan.StepCosts([plan.Point(32, 1024, 500, 0.02, 0.01, 0.015), plan.Point(64, 4096, 500, 0.05, 0.02, 0.03),
                        plan.Point(32, 1024, 4000, 0.03, 0.012, 0.02), plan.Point(64, 4096, 4000, 0.07, 0.03, 0.04)])
PHASES = [Phase("level", 100, 0.1, cap=120), Phase("cycle", 40, 0.05),
          Phase("level", 100, 0.2, cap=120), Phase("cycle", 40, 0.06),
          Phase("final", 160, 0.07, count=2),
          Phase("polish", 150, 0.25, cap=240, count=2, cycle_units=160, cycle_s=0.07)]


def simulate(phases, step_scale: float = 1.0):
    """The events of a run that goes through ``phases`` with their planned counts, its steps
    taking ``step_scale`` times the planned seconds (cycles as planned): [(time, event, fields)]."""
    t, out = 0.0, []

    def units(stage, n, unit_s):
        nonlocal t
        out.append((t, "stage", {"stage": stage}))
        for i in range(1, int(n) + 1):
            t += unit_s
            out.append((t, "progress", {"stage": stage, "iteration": i, "iterations": n}))

    for p in phases:
        if p.kind == "level":
            units("geometry", p.units, p.unit_s * step_scale)
        elif p.kind == "cycle":
            units("material:constant", p.units, p.unit_s)
            out.append((t, "stage", {"stage": "remesh"}))
        elif p.kind == "final":
            for _ in range(int(p.count)):
                units("material:diffuse", p.units, p.unit_s)
        else:
            for _ in range(int(p.count)):
                units("polish", p.units, p.unit_s * step_scale)
                units("material:specular", p.cycle_units, p.cycle_s)
    out.append((t, "stage", {"stage": "material:check"}))
    return out, t


def test_the_phases_add_up_to_the_plans_time():
    config = ReconstructConfig(**{**PRESETS["draft"], "polish_rounds": 2}, material="staged")
    p = plan.predict("draft", config, COSTS, lambda size: size * size, 8, staged=True)
    assert [ph.kind for ph in p.phases] == ["level", "cycle"] * len(p.levels) + ["final", "polish"]
    # Draft as it ships runs no polish round
    shipped = plan.predict("draft", ReconstructConfig(**PRESETS["draft"], material="staged"), COSTS,
                           lambda size: size * size, 8, staged=True)
    assert [ph.kind for ph in shipped.phases][-1] == "final"
    assert sum(ph.seconds for ph in p.phases) == pytest.approx(p.geometry_s + p.material_s + p.polish_s)
    assert p.to_json()["phases"][0]["kind"] == "level"
    # the preset event's JSON gives the same estimate as the plan itself
    assert Remaining.from_plan(p.to_json()).seconds(0.0) == pytest.approx(Remaining.from_plan(p).seconds(0.0), rel=1e-5)
    constant = plan.predict("draft", ReconstructConfig(**PRESETS["draft"]), COSTS, lambda s: s * s, 8, staged=False)
    assert {ph.kind for ph in constant.phases} == {"level"}


def test_a_run_at_the_planned_pace_is_told_the_planned_end_throughout():
    events, end = simulate(PHASES)
    remaining = Remaining(list(PHASES))
    assert remaining.seconds(0.0) == pytest.approx(sum(p.seconds for p in PHASES) + END_S)
    for t, event, fields in events:
        remaining.observe(event, fields, t)
        if fields.get("iteration") != fields.get("iterations"):  # at its planned count a level may go on
            assert t + remaining.seconds(t) == pytest.approx(end + END_S, rel=1e-6, abs=1e-6), (t, fields)
    assert not remaining.active


def test_slower_steps_carry_to_the_later_levels_and_rounds_not_to_cycles():
    events, end = simulate(PHASES, step_scale=2.0)
    remaining = Remaining(list(PHASES))
    for t, event, fields in events:
        remaining.observe(event, fields, t)
        if event == "stage" and fields["stage"] == "material:constant":
            break  # level 0 done, at twice its planned seconds per step
    assert remaining.pace["step"] == pytest.approx(2.0) and remaining.pace["cycle"] == 1.0
    later_steps = 2.0 * (100 * 0.2 + 2 * 150 * 0.25)
    cycles = 40 * 0.05 + 40 * 0.06 + 2 * 160 * 0.07 + 2 * 160 * 0.07
    assert remaining.seconds(t) == pytest.approx(later_steps + cycles + END_S)
    for t, event, fields in events[events.index((t, event, fields)) + 1:]:
        remaining.observe(event, fields, t)
        if fields.get("iteration") != fields.get("iterations"):
            assert t + remaining.seconds(t) == pytest.approx(end + END_S, rel=1e-6, abs=1e-6)


def test_a_level_past_its_planned_steps_expects_half_of_what_its_cap_allows():
    remaining = Remaining(list(PHASES))
    remaining.observe("stage", {"stage": "geometry"}, 0.0)
    remaining.observe("progress", {"stage": "geometry", "iteration": 110}, 11.0)  # planned 100, cap 120
    later = sum(p.seconds for p in PHASES[1:])
    assert remaining.seconds(11.0) == pytest.approx(0.5 * 10 * 0.1 + later + END_S)
    # a stale heartbeat (another stage's fields) does not move the count
    remaining.observe("progress", {"stage": "material:constant", "iteration": 3}, 11.5)
    assert remaining.current.done == 110


def test_a_time_budget_caps_the_time_left():
    remaining = Remaining(list(PHASES), budget_s=30.0)
    remaining.observe("stage", {"stage": "geometry"}, 0.0)
    assert remaining.seconds(10.0) == pytest.approx(20.0 + END_S)
    assert remaining.seconds(40.0) == pytest.approx(END_S)


def test_without_phases_there_is_no_estimate():
    assert Remaining.from_plan({"levels": []}).seconds(5.0) is None
    assert Remaining.from_plan(None).seconds(5.0) is None


def test_a_staged_runs_progress_counts_down_through_the_material_stages(tmp_path):
    """A real run: its progress events' fraction and time left follow the plan through the
    material stages and polish (before, the fraction came from the geometry levels only and
    sat at 0.999 from the last level on)."""
    capture = tmp_path / "capture"
    run_cli("synth", "--out", capture, "--views", 6, "--resolution", 32, "--spp", 16, "--held-out", 0, check=True)
    run = tmp_path / "run"
    proc = run_cli("reconstruct", capture, "--out", run, "--preset", "draft", "--init", "sphere",
                   "--level-iterations", 20, "--max-levels", 2, "--max-size", 16, "--coarse-size", 16,
                   "--initial-faces", 320,
                   "--material", "staged", timeout=900,
                   env={"SFT_RECONSTRUCT_SETTINGS": json.dumps({"polish_rounds": 2})})  # Draft runs none
    assert proc.returncode == 0, proc.stderr[-2000:]
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    preset = next(e for e in events if e["event"] == "preset" and e.get("plan"))
    assert [p["kind"] for p in preset["plan"]["phases"]][-2:] == ["final", "polish"]
    start = events.index(preset)
    last_level = max(i for i, e in enumerate(events) if e["event"] == "stage" and e["stage"] == "geometry")
    paced = [e for e in events[start:] if e["event"] == "progress" and e.get("fraction") is not None]
    after = [e for e in events[last_level:] if e["event"] == "progress" and e.get("fraction") is not None]
    assert paced and after
    assert all(e["eta_s"] is not None and e["eta_s"] >= 0 for e in paced)
    assert min(e["fraction"] for e in after) < 0.95  # the material stages still to come are counted
    # within a material stage, once it reports, the heartbeat repeats its stage, not the level's
    stage = None
    for e in events:
        if e["event"] == "stage":
            stage, reported = e["stage"], False
        elif e["event"] == "progress" and stage and stage.startswith("material"):
            reported = reported or e["stage"] == stage
            assert not reported or e["stage"] == stage, (stage, e)
            assert e.get("fraction") is not None, e  # sent through the run's progress: with the time left
    end = events[-1]["time"]
    # the time left after the last level's start, against the time the run really took
    e = after[0]
    assert abs(e["time"] + e["eta_s"] - end) < 0.6 * end, (e, end)


def test_a_resumed_run_carries_the_phases_done_and_their_pace(tmp_path):
    """--resume: the plan of the process that began the run, its events replayed (a line cut
    short by the crash skipped); the level it was in starts again, found by its number."""
    from backend.planning.remaining import resumed

    events, _ = simulate(PHASES, step_scale=2.0)
    cut = next(i for i, (t, e, f) in enumerate(events) if e == "progress" and f["stage"] == "geometry"
               and f["iteration"] == 50 and t > 20)  # halfway through level 1
    lines = [json.dumps({"event": "preset", "time": 0.0, "plan": {"phases": [p.to_json() for p in PHASES]}})]
    lines += [json.dumps({"event": e, "time": t, **f}) for t, e, f in events[:cut]]
    path = tmp_path / "events.jsonl"
    path.write_text("\n".join(lines) + '\n{"event": "progr')
    remaining = resumed(path)
    assert remaining.index == 2 and remaining.current is None and remaining.pace["step"] == pytest.approx(2.0)
    remaining.observe("stage", {"stage": "geometry", "level": 1}, 100.0)  # level 1 again
    assert remaining.index == 2
    later = 2.0 * 2 * 150 * 0.25 + 40 * 0.06 + 2 * 160 * 0.07 + 2 * 160 * 0.07
    assert remaining.seconds(100.0) == pytest.approx(2.0 * 100 * 0.2 + later + END_S)
    assert resumed(tmp_path / "missing.jsonl") is None


def test_stages_the_plan_has_not_leave_the_estimate_standing():
    """A constant-material plan has levels only; material stages, polish or a final cycle it
    did not plan for must not break the estimate."""
    remaining = Remaining([Phase("level", 100, 0.1, cap=120), Phase("level", 100, 0.2, cap=120)])
    for t, stage in enumerate(("geometry", "material:constant", "remesh", "geometry", "material:diffuse", "polish",
                               "material:specular")):
        remaining.observe("stage", {"stage": stage}, float(t))
        assert remaining.seconds(float(t)) >= END_S
    remaining.observe("stage", {"stage": "material:check"}, 9.0)
    assert remaining.seconds(9.0) == END_S
