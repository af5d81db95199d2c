"""A new run's first cost probe (shadow gradients, one more bounce) runs after the first level's
first geometry step instead of before it: the same probe on the same initial mesh, views, seeds
and material, so the same verdicts where its timings agree; the steps after it follow them, and
the decision kept beside the capture is the complete one."""

from __future__ import annotations

import json

import numpy as np

from backend.optimize.effect_costs import CostRule, EffectCost
from tests.helpers import run_cli
from tests.render.test_effects import _staged_appearance


def test_the_deferred_probe_gives_the_up_front_verdicts(tmp_path):
    from backend.geometry.mesh import Mesh

    app, mesh, material, views = _staged_appearance(tmp_path, "--lighting", "env", "--env", "sky")
    estimate = Mesh(mesh.vertices * 1.06, mesh.faces)  # off the truth: the gradient is not noise
    app.decide(estimate, material, views, reason="initial mesh")
    up_front = app.decision.measured["costs"]
    assert set(up_front) == {"shadows", "bounce"}

    deferred, mesh, material, views = _staged_appearance(tmp_path / "again", "--lighting", "env", "--env", "sky")
    deferred.defer_costs = True
    deferred.decide(Mesh(mesh.vertices * 1.06, mesh.faces), material, views, reason="initial mesh")
    assert deferred.costs_pending and deferred.decision.measured["costs"] == "pending"
    assert deferred.decision.shadows is False  # the cheap step while the probe waits
    # the first steps train the material: the probe measures on the material it was deferred from
    trained = {n: np.asarray(z, np.float64) + 0.3 for n, z in material.parameters().items()}
    material.load_parameters(trained)
    deferred.run_pending_costs()
    assert not deferred.costs_pending
    for name, params in material.parameters().items():  # and the steps' material comes back
        assert np.allclose(np.asarray(params, np.float64), trained[name], atol=1e-5)
    later = deferred.decision.measured["costs"]
    assert set(later) == set(up_front)
    rule = CostRule()
    for name, cost in later.items():
        first = up_front[name]
        assert np.isclose(cost["share"], first["share"], rtol=1e-3, atol=1e-6), name
        assert np.isclose(cost["z"], first["z"], rtol=1e-3, atol=1e-2), name
        # the verdict the deferred shares give at the up-front timings is the up-front verdict
        timed_as_first = EffectCost(name, first["seconds"], first["base_seconds"], cost["share"], cost["noise"],
                                    cost["z"], cap=first.get("cap"))
        assert rule.pays(timed_as_first) == first["pays"], name
    assert deferred.history[-1]["reason"] == "initial mesh: cost probe"
    assert deferred.decision.shadows == later["shadows"]["pays"]


def test_a_first_run_steps_before_its_cost_probe_and_caches_the_complete_decision(tmp_path):
    capture = tmp_path / "capture"
    run_cli("synth", "--out", capture, "--views", 6, "--resolution", 32, "--spp", 16, "--held-out", 0,
            "--lighting", "env", "--env", "sky", check=True)
    options = ["--max-size", "32", "--coarse-size", "32", "--initial-faces", "600", "--spp", "4", "--init", "carve",
               "--iterations", "3", "--material", "auto", "--effects", "auto", "--texture-stage", "off"]

    def events(out):
        proc = run_cli("reconstruct", capture, "--out", out, *options, check=True)
        return [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]

    first = events(tmp_path / "one")
    decisions = [e for e in first if e["event"] == "effects"]
    step = next(e for e in first if e["event"] == "stage" and e["stage"] == "geometry")
    assert decisions[0]["measured"]["costs"] == "pending"
    probe = next(e for e in decisions if e["reason"] == "initial mesh: cost probe")
    assert probe["time"] > step["time"]  # after the first step
    assert set(probe["measured"]["costs"]) == {"shadows", "bounce"}
    assert probe["enabled"]["shadows"] == probe["measured"]["costs"]["shadows"]["pays"]

    second = events(tmp_path / "two")
    cached = next(e for e in second if e["event"] == "effects")
    assert cached["measured"]["cache"] == "hit" and cached["measured"]["costs"] == probe["measured"]["costs"]
    assert cached["enabled"] == probe["enabled"]
    assert not [e for e in second if e["event"] == "effects" and e["reason"].endswith("cost probe")]


def test_the_steps_after_the_probe_follow_its_verdicts(tmp_path, monkeypatch):
    """Every effect paying (the rule's verdict fixed, the probe still measured): the first step
    renders without shadow gradients at the measured depth, the steps after the probe with both."""
    from backend import variant

    variant.choose(None)
    from backend.capture.load import load_capture
    from backend.optimize import effect_costs
    from backend.optimize.config import ReconstructConfig
    from backend.optimize.objective import Objective
    from backend.optimize.run import reconstruct
    from backend.optimize.run_folder import RunFolder

    run_cli("synth", "--out", tmp_path / "capture", "--views", 6, "--resolution", 32, "--spp", 16, "--held-out", 0,
            "--lighting", "env", "--env", "sky", check=True)
    monkeypatch.setattr(effect_costs.CostRule, "pays", lambda self, cost: True)
    built = []

    def recording(mesh, material, views, settings, *args, **kwargs):
        built.append(settings)
        return Objective(mesh, material, views, settings, *args, **kwargs)

    events = []
    config = ReconstructConfig(init="carve", material="staged", effects="auto", max_size=32, coarse_size=32,
                               initial_faces=600, spp=4, iterations=3, max_levels=1, texture_stage="off")
    folder = RunFolder.create(tmp_path / "run", resume=False, overwrite=False)
    assert reconstruct(load_capture(tmp_path / "capture"), folder, config,
                       lambda name, **fields: events.append((name, fields)), objective_factory=recording).exit_code == 0
    probe = next(f for n, f in events if n == "effects" and f["reason"] == "initial mesh: cost probe")
    assert probe["enabled"]["shadows"] is True
    first, after = built[0], built[1]
    assert first.sppi == 0 and after.sppi > 0
    bounce = "bounce" in probe["measured"]["costs"]  # not a candidate when the depth is already the probe's
    assert after.max_depth == first.max_depth + int(bounce) == probe["enabled"]["max_depth"]


def test_a_run_stopped_before_its_probe_leaves_the_rest_of_the_decision(tmp_path):
    """The decision without its cost verdicts is kept at once: the next run on the capture skips
    the effects renders and still runs the cost probe after its own first step."""
    from backend.events import null_emitter
    from backend.geometry.mesh import Mesh
    from backend.optimize.appearance import Appearance

    stopped, mesh, material, views = _staged_appearance(tmp_path, "--lighting", "env", "--env", "sky")
    estimate = Mesh(mesh.vertices * 1.06, mesh.faces)
    stopped.defer_costs = True
    stopped.decide(estimate, material, views, reason="initial mesh")
    assert stopped.costs_pending  # stopped here: its probe never runs

    again = Appearance(stopped.capture, stopped.config, null_emitter())
    again.defer_costs = True
    again.decide(estimate, again.initial_material(mesh, views), views, reason="initial mesh")
    assert again.decision.measured["cache"] == "hit" and again.costs_pending
    assert again.history[-1]["measured"]["bounces"] == stopped.history[-1]["measured"]["bounces"]
    again.run_pending_costs()
    assert set(again.decision.measured["costs"]) == {"shadows", "bounce"}

    third = Appearance(stopped.capture, stopped.config, null_emitter())
    third.defer_costs = True
    third.decide(estimate, third.initial_material(mesh, views), views, reason="initial mesh")
    assert not third.costs_pending and third.decision.measured["costs"] == again.decision.measured["costs"]
