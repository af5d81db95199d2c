"""The Plan button: ``reconstruct --plan`` through the real backend as a job (headless path),
its line in the Reconstruct panel under the Quality presets, and no run folder left."""

from __future__ import annotations

import bpy

from backend.planning import accuracy_forecast as forecast

from .test_panels import draw


def test_plan_button_shows_each_presets_time_on_this_capture(context, tiny_capture):
    sft = context.scene.sft
    sft.capture_dir, sft.time_budget = str(tiny_capture), 0.0  # no budget: every preset's own time
    log = draw("SFT_PT_reconstruct", context)
    assert ("label", "This capture: press Plan") in log and ("operator", "sft.plan", True) in log
    assert bpy.ops.sft.plan() == {"FINISHED"}
    text = sft.plan_text
    assert text.startswith("Draft \u2248 ") and "Balanced \u2248 " in text and "Final \u2248 " in text, text
    assert text.endswith("on this capture")
    minutes = [float(part.split("\u2248 ")[1].split(" min")[0]) for part in text.split(", ")]
    assert 0 < minutes[0] < minutes[1] < minutes[2], text
    log = draw("SFT_PT_reconstruct", context)
    assert all(("label", part) in log for part in text.split(", ")), log  # one line per preset
    if forecast.load_gains():  # each preset's predicted held-out PSNR from this capture's probe
        assert text.count(" dB)") >= 1, text
        assert ("label", "dB: predicted PSNR of views the run never fits") in log
    assert not (tiny_capture / "runs").exists(), "--plan writes nothing"
    sft.time_budget = minutes[1] / 2  # a budget ends the longer presets: said so
    assert bpy.ops.sft.plan() == {"FINISHED"}
    assert sft.plan_text.count("(budget)") == 2, sft.plan_text


def test_plan_without_cameras_is_refused(context, tmp_path):
    context.scene.sft.capture_dir = str(tmp_path)
    try:
        bpy.ops.sft.plan()
    except RuntimeError as err:
        assert "no cameras" in str(err)
    assert context.scene.sft.plan_text == ""
