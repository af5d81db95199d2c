"""Track Accuracy in the add-on (off by default): the run is asked to track it, and the curve the backend redraws
(RUN/accuracy_time.png) reaches the Reconstruct panel on every ``accuracy`` event."""

from __future__ import annotations

import sys
import time
import types
from importlib import import_module

import bpy

from .conftest import SCRIPTED_BACKEND
from .test_panels import RecordingLayout


class CurveLayout(RecordingLayout):
    def _child(self, *args, **kwargs):
        return CurveLayout(self.log)

    row = column = box = split = _child

    def template_icon(self, icon_value=0, scale=1.0):
        self.log.append(("template_icon", icon_value, scale))


def draw(context) -> list:
    log = []
    bpy.types.SFT_PT_reconstruct.draw(types.SimpleNamespace(layout=CurveLayout(log)), context)
    return log


def test_track_accuracy_is_off_by_default_and_asks_the_backend_when_on(context, extension):
    """Off by default: it holds every 8th view out of the fit (a capture without held-out views)."""
    reconstruct = import_module(f"{extension.__name__}.addon.operators.reconstruct")
    sft = context.scene.sft
    assert not sft.track_accuracy and "--track-accuracy" not in reconstruct.method_args(sft)
    assert ("prop", "track_accuracy") in draw(context)  # still in the panel
    sft.track_accuracy = True
    assert "--track-accuracy" in reconstruct.method_args(sft)
    sft.track_accuracy = False


def test_the_panel_curve_is_updated_in_place_from_accuracy_events(context, addon, tmp_path):
    run = tmp_path / "run"
    job = addon.jobs.ReconstructJob(sys.executable, ["reconstruct", "c", "--out", str(run), "--mode", "accuracy",
                                                    "--steps", "4", "--delay", "0.3"], run, "Reconstruction",
                                    root=SCRIPTED_BACKEND)
    curve = addon.accuracy_curve
    try:
        assert not curve.shown() and not any(e[0] == "template_icon" for e in draw(context))
        reds = []
        while job.step(context):
            if curve.shown():
                reds.append(round(float(curve.pixels()[..., 0].mean()) * 255))
            time.sleep(0.02)
    finally:
        if job.running:
            job.process.kill()
    # one preview image, refilled from each new figure: step k's figure has red 20 k
    assert len(set(reds)) >= 3 and reds == sorted(reds) and set(reds) <= {20, 40, 60, 80}, reds
    assert curve.pixels().shape == (20, 40, 4) and round(float(curve.pixels()[..., 0].mean()) * 255) == 80
    assert job.state.accuracy == [(0.5, 16.0), (1.0, 17.0), (1.5, 18.0), (2.0, 19.0)]
    log = draw(context)
    assert ("template_icon", curve.icon_id(), 9.0) in log
    labels = [e[1] for e in log if e[0] == "label"]
    assert "Held-out PSNR 19.0 dB (+3.0 dB in 2s, 4 scores)" in labels
    assert "Next level (128 px) would have bought ~+1.5 dB (extrapolated)" in labels
    addon.jobs.ReconstructJob(sys.executable, ["reconstruct", "c", "--out", str(tmp_path / "next"), "--steps", "1"],
                              tmp_path / "next", "Reconstruction", root=SCRIPTED_BACKEND).run_blocking(context, 0.02)
    assert not curve.shown() and not any(e[0] == "template_icon" for e in draw(context))  # a new run's own curve
