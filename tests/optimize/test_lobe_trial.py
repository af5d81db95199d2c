"""The specular lobe on trial (backend/optimize/lobe_trial.py), with real renders: a lobe
that an effects re-check turns on mid-run stays when, fitted without every 4th view, it
renders those views at least as well, and otherwise the material from before it comes back
and later re-checks leave the lobe off."""

from __future__ import annotations

import numpy as np

from backend import variant

variant.choose()

from backend.render import effects  # noqa: E402
from tests.render.test_effects import _staged_appearance  # noqa: E402


def _diffuse_first(tmp_path):
    """A glossy object judged diffuse at first, its constants fitted diffuse-only."""
    app, mesh, material, views = _staged_appearance(tmp_path)
    events = []
    app.emit = lambda kind, **fields: events.append((kind, fields))
    app.decision = effects.EffectsDecision(specular=False, max_depth=2)
    material.disable("specular")
    app.specular_off = True
    app.driver.schedule.stage = "diffuse"
    return app, mesh, material, views, events


def test_a_lobe_that_renders_the_views_better_is_kept(tmp_path):
    app, mesh, material, views, events = _diffuse_first(tmp_path)
    app.recheck(mesh, material, views, level=1)
    assert app.decision.specular and app.lobe.pending
    left_out = {views[2].name, views[6].name}  # 8 views: every 4th is left out of the trial's fits
    assert app.lobe.left_out == left_out and [v.name for v in app.lobe.fitting(views)] == [
        v.name for v in views if v.name not in left_out]
    app.material_cycle(mesh, material, views, level=1)
    record = app.lobe.records[-1]
    assert set(record["judged_on"]) == left_out and app.lobe.fitting(views) == views
    assert record["kept"] and record["loss_after"] <= record["loss_before"], record
    assert app.decision.specular and "specular" in material.trainable and app.lobe.refused is None
    kinds = [f["reason"] for k, f in events if k == "effects"]
    assert kinds[0].startswith("level 1") and kinds[-1].startswith("the specular lobe kept"), kinds


def test_a_lobe_that_lost_the_views_is_refused_and_stays_off(tmp_path):
    app, mesh, material, views, events = _diffuse_first(tmp_path)
    albedo = material.values("albedo").copy()
    app.recheck(mesh, material, views, level=1)
    assert app.lobe.pending and float(material.values("specular").mean()) > 0
    material.set_values("albedo", np.full_like(albedo, 0.02))  # a cycle that lost the views
    app._judge_lobe(mesh, material)
    record = app.lobe.refused
    assert record is not None and not record["kept"] and record["loss_after"] > record["loss_before"]
    assert np.allclose(material.values("albedo"), albedo)  # the material from before the lobe
    assert np.all(material.values("specular") < 1e-5) and "specular" not in material.trainable
    assert not app.decision.specular and not app.lobe.pending
    effects_events = [f for k, f in events if k == "effects"]
    assert effects_events[-1]["reason"].startswith("the specular lobe refused")
    assert effects_events[-1]["measured"]["lobe_trial"] == record
    app.recheck(mesh, material, views, level=2)  # the highlights are still measured: it stays off
    assert not app.decision.specular and "tried earlier" in app.decision.reasons["specular"]
    assert np.all(material.values("specular") < 1e-5) and not app.lobe.pending
