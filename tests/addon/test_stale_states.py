"""Stale and wrong states in the sidebar: the Plan line goes when the capture or a setting it
was measured with changes (and a Plan that finishes after such a change is not shown);
Reconstruct, Plan and Solve Cameras do not run at once, nor Install Backend under a run; a
capture with point lights switches Lighting to them."""

from __future__ import annotations

import sys
import time

import bpy
import pytest

from .conftest import SCRIPTED_BACKEND
from .test_capture_ops import expect_error
from .test_panels import draw
from .test_relit_lighting import _capture

PLAN = "Draft \u2248 1 min, Balanced \u2248 4 min, Final \u2248 9 min on this capture"


@pytest.mark.parametrize("name, value", [
    ("capture_dir", "/elsewhere"), ("env_path", "/elsewhere/sky.exr"), ("env_strength", 2.0), ("env_rotation", 30.0), ("map_calibrated", True),
    ("time_budget", 5.0), ("track_accuracy", True), ("material", "CONSTANT"), ("init", "SPHERE"),
    ("effects", "ALL"), ("lighting", "FLASH"), ("extra_args", "--max-size 32")])
def test_a_changed_setting_clears_the_plan_line(context, name, value):
    sft = context.scene.sft
    sft.plan_text = PLAN
    setattr(sft, name, value)
    assert sft.plan_text == "", name
    assert ("label", "This capture: press Plan") in draw("SFT_PT_reconstruct", context)


def test_choosing_a_preset_keeps_the_plan_line(context):
    """The line predicts every preset: picking one of them changes nothing it measured."""
    sft = context.scene.sft
    sft.plan_text = PLAN
    sft.preset = "draft"
    sft.preview_samples = 8
    assert sft.plan_text == PLAN


def test_importing_cameras_clears_the_plan_line(context, tmp_path):
    capture = _capture(tmp_path / "capture", lights=False)
    sft = context.scene.sft
    sft.capture_dir = str(capture)
    sft.plan_text = PLAN
    assert bpy.ops.sft.import_cameras(filepath=str(capture / "capture.json")) == {"FINISHED"}
    assert sft.capture_dir == str(capture) and sft.plan_text == ""


def test_a_plan_of_other_settings_is_not_shown(context, addon, tmp_path):
    """What Plan measured is compared with the scene's settings when it ends."""
    plan = __import__(f"{addon.__name__}.operators.preset_plan", fromlist=["preset_plan"])
    capture = _capture(tmp_path / "capture", lights=False)
    sft = context.scene.sft
    sft.capture_dir, sft.extra_args = str(capture), "--mode bad-input"  # the scripted backend ends at once
    job = plan.PlanJob(sys.executable, plan.plan_args(capture, sft), root=SCRIPTED_BACKEND)
    try:
        job.run_blocking(context, 0.02)
        assert plan._measured_now(context, job)
        sft.time_budget = 12.0
        assert not plan._measured_now(context, job)
    finally:
        addon.jobs.ACTIVE.pop("plan", None)


def _running(addon, kind: str, tmp_path):
    """A scripted backend job of ``kind`` that runs until it is stopped."""
    run = tmp_path / kind
    return addon.jobs.Job(sys.executable, ["reconstruct", "c", "--out", str(run), "--steps", "10000", "--delay", "0.05"],
                          run, kind=kind, root=SCRIPTED_BACKEND)


@pytest.mark.parametrize("kind, refused, message", [
    ("plan", ("reconstruct", "reconstruct_resume", "solve_cameras"), "Plan is measuring the capture"),
    ("reconstruct", ("plan", "solve_cameras", "install_backend"), "a reconstruction is running"),
    ("solve", ("reconstruct", "reconstruct_resume", "plan"), "the cameras are being solved")])
def test_reconstruct_plan_and_solve_exclude_each_other(context, addon, tmp_path, kind, refused, message):
    capture = _capture(tmp_path / "capture", lights=False)
    sft = context.scene.sft
    sft.capture_dir = str(capture)
    assert bpy.ops.sft.reconstruct.poll() and bpy.ops.sft.plan.poll()  # nothing runs: both may start
    job = _running(addon, kind, tmp_path)
    try:
        for name in refused:
            op = getattr(bpy.ops.sft, name)
            assert not op.poll(), name
            expect_error(op, "poll()", message)
    finally:
        job.process.kill()
        while job.step(context):
            time.sleep(0.02)
        addon.jobs.ACTIVE.pop(kind, None)
    assert bpy.ops.sft.reconstruct.poll() and bpy.ops.sft.plan.poll()


def test_a_capture_with_point_lights_sets_lighting_to_them(context, tmp_path):
    sft = context.scene.sft
    assert sft.lighting == "AUTO"
    plain = _capture(tmp_path / "plain", lights=False)
    assert bpy.ops.sft.import_cameras(filepath=str(plain / "capture.json")) == {"FINISHED"}
    assert sft.lighting == "AUTO"  # no lights of its own: the lighting is still to be chosen
    lit = _capture(tmp_path / "lit", lights=True)
    assert bpy.ops.sft.import_cameras(filepath=str(lit / "capture.json")) == {"FINISHED"}
    assert sft.lighting == "CAPTURED"
    labels = [entry[1] for entry in draw("SFT_PT_reconstruct", context) if entry[0] == "label"]
    assert "Lighting: the capture's point lights (1)" in labels and "No lighting: Import Environment Map" not in labels
