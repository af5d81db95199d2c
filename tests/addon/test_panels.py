"""The sidebar panels' draw code, run against a layout that records what it draws and
checks every property, operator and icon name against Blender's RNA (panels cannot be
drawn in background mode); drawing reads no file."""

from __future__ import annotations

import builtins
import contextlib
import io
import json
import os
import sys
import time
import types

import bpy
import pytest

from tests.helpers import REPO

from .conftest import SCRIPTED_BACKEND

ICONS = set(bpy.types.UILayout.bl_rna.functions["label"].parameters["icon"].enum_items.keys())


class RecordingLayout:
    def __init__(self, log: list):
        self.log = log
        self.enabled = True

    def _child(self, *args, **kwargs):
        return RecordingLayout(self.log)

    row = column = box = split = _child

    def prop(self, data, name, **kwargs):
        assert name in data.bl_rna.properties, name
        self.log.append(("prop", name))

    def operator(self, idname, icon="NONE", **kwargs):
        module, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), name), idname
        assert icon in ICONS, icon
        self.log.append(("operator", idname, self.enabled))
        return types.SimpleNamespace()  # the operator's properties, as Blender returns them

    def label(self, text="", icon="NONE", **kwargs):
        assert icon in ICONS, icon
        self.log.append(("label", text))

    def progress(self, factor=0.0, type="BAR", text=""):
        assert 0.0 <= factor <= 1.0
        self.log.append(("progress", round(factor, 3), text))


def shipped_kind(kind: str) -> tuple[dict, bool]:
    """The shipped calibration file's entries for ``kind`` (the point-lit ones when it has no
    such kind) and whether they are that kind's own."""
    calibration = json.loads((REPO / "backend" / "presets.json").read_text())
    own = calibration.get("kinds", {}).get(kind)
    return (own["presets"], True) if own else (calibration["presets"], False)


def expected_cost(preset: str, kind: str = "point") -> str:
    """What the panel should say for a preset, read straight from the shipped calibration file."""
    entries, _ = shipped_kind(kind)
    machine = json.loads((REPO / "backend" / "presets.json").read_text())["machine"]
    entry = entries.get(preset)
    if entry is None:
        return "not calibrated"
    by = f" (no gain over {entry['dominated_by'].capitalize()})" if entry.get("dominated_by") else ""
    return f"~{entry['expected_minutes']:.3g} min, F1 {entry['expected_f1']:.2f}{by} on {machine}"


def draw(panel_name: str, context) -> list:
    log = []
    getattr(bpy.types, panel_name).draw(types.SimpleNamespace(layout=RecordingLayout(log)), context)
    return log


def test_panels_draw_in_an_empty_scene(context):
    log = {name: draw(name, context) for name in
           ("SFT_PT_capture", "SFT_PT_cameras", "SFT_PT_reconstruct", "SFT_PT_preview")}
    assert ("operator", "sft.import_video", True) in log["SFT_PT_capture"]
    assert ("operator", "sft.solve_cameras", True) in log["SFT_PT_cameras"]
    assert ("operator", "sft.reconstruct", True) in log["SFT_PT_reconstruct"]
    labels = [entry[1] for entry in log["SFT_PT_reconstruct"] if entry[0] == "label"]
    # the default lighting (Auto) fits a map or a flash: the HDR-lit kind's figures where the file has them
    titles = (("draft", "Draft"), ("balanced", "Balanced"), ("final", "Final"))
    assert labels[:3] == [f"{title}: {expected_cost(key, 'environment')}" for key, title in titles]
    assert ("Times measured on an HDR-lit object" if shipped_kind("environment")[1] else
            "Times measured on a point-lit object; HDR-lit captures take longer") in labels
    assert any(label.startswith("Chosen by a short probe") for label in labels)  # the default: Auto
    props = [entry[1] for entry in log["SFT_PT_reconstruct"] if entry[0] == "prop"]
    assert props == ["preset", "time_budget", "track_accuracy", "material", "init", "effects", "lighting",
                     "show_labels"], "the method's settings and the labels overlay's toggle, no free text"
    context.scene.sft.lighting = "CAPTURED"
    labels = [e[1] for e in draw("SFT_PT_reconstruct", context) if e[0] == "label"]
    assert "No lighting: Import Environment Map" in labels
    # the capture's own lights: the point-lit kind's figures
    assert labels[:3] == [f"{title}: {expected_cost(key)}" for key, title in titles]
    assert "Times measured on a point-lit object" in labels
    context.scene.sft.lighting = "ESTIMATE"
    assert [e[1] for e in draw("SFT_PT_reconstruct_advanced", context) if e[0] == "prop"] == ["extra_args"]
    context.scene.sft.init = "OBJECT"
    assert ("prop", "init_object") in draw("SFT_PT_reconstruct", context)
    assert ("operator", "sft.relit_preview", True) in log["SFT_PT_preview"]
    assert not any(e[:2] == ("operator", "sft.reconstruct_resume") for e in log["SFT_PT_reconstruct"])


def test_reconstruct_panel_offers_resume_for_an_unfinished_run(context, addon, tmp_path):
    (tmp_path / "state").mkdir()
    (tmp_path / "state" / "state.json").write_text("{}")
    (tmp_path / "command.json").write_text('{"argv": ["reconstruct", "c", "--out", "r"]}')
    context.scene.sft.run_dir = str(tmp_path)  # its update callback reads the folder
    try:
        assert ("operator", "sft.reconstruct_resume", True) in draw("SFT_PT_reconstruct", context)
        (tmp_path / "report.json").write_text("{}")  # finished: nothing to resume
        addon.capture_state.refresh(context.scene)  # what the run's end (a job event) does
        assert not any(e[:2] == ("operator", "sft.reconstruct_resume") for e in draw("SFT_PT_reconstruct", context))
    finally:
        context.scene.sft.run_dir = ""


def test_reconstruct_panel_shows_progress_and_cancel(context, addon, tmp_path):
    run = tmp_path / "run"
    job = addon.jobs.ReconstructJob(sys.executable, ["reconstruct", "c", "--out", str(run), "--steps", "400",
                                                    "--delay", "0.05"], run, "Reconstruction", root=SCRIPTED_BACKEND)
    try:
        while job.state.iteration < 3:
            job.step(context)
            time.sleep(0.02)
        log = draw("SFT_PT_reconstruct", context)
        progress = next(e for e in log if e[0] == "progress")
        assert 0 < progress[1] < 0.1 and "ETA" in progress[2]
        assert any(e[0] == "label" and e[1].startswith("geometry (level 0)  it ") and "loss" in e[1] for e in log)
        assert ("operator", "sft.reconstruct_cancel", True) in log
        assert not any(e[:2] == ("operator", "sft.reconstruct") for e in log)  # no second run
        # a fitted lighting's line (the protocol's lighting event, as an estimate run emits it)
        job.state.update({"event": "lighting", "when": "restarted", "stage": None, "model": "estimate",
                          "frame": "world", "resolution": [16, 8]})
        assert ("label", "Lighting: estimated map 16x8, fitting again on the final surface") in draw(
            "SFT_PT_reconstruct", context)
        # the plan's promise beside the run's own estimate (the protocol's preset event)
        job.state.update({"event": "preset", "preset": "draft", "predicted_minutes": 2.5})
        assert any(e[0] == "label" and e[1].startswith("Planned 2m 30s; now ") for e in draw("SFT_PT_reconstruct", context))
        assert bpy.ops.sft.reconstruct_cancel() == {"FINISHED"}
        assert any(e == ("label", "Stopping after the current step...") for e in draw("SFT_PT_reconstruct", context))
        job.run_blocking(context, interval=0.02)
        log = draw("SFT_PT_reconstruct", context)
        assert ("label", "Cancelled: the last snapshot is kept") in log
        assert ("operator", "sft.export_gltf", True) in log
    finally:
        if job.running:
            job.process.kill()
    with pytest.raises(RuntimeError):  # nothing left to cancel
        bpy.ops.sft.reconstruct_cancel()


@contextlib.contextmanager
def file_access_counted():
    """Count the calls that open, list or stat a file (observing them: each still runs)."""
    calls = []
    patched = [(builtins, "open"), (io, "open"), (os, "open"), (os, "scandir"), (os, "listdir"), (os, "stat")]
    originals = [getattr(module, name) for module, name in patched]

    def counting(name, original):
        def wrapper(*args, **kwargs):
            calls.append((name, args[0] if args else None))
            return original(*args, **kwargs)
        return wrapper

    for (module, name), original in zip(patched, originals):
        setattr(module, name, counting(name, original))
    try:
        yield calls
    finally:
        for (module, name), original in zip(patched, originals):
            setattr(module, name, original)


def test_drawing_the_panels_reads_no_file(context, addon, tmp_path):
    """A capture with frames, masks, cameras with point lights, a resumable run and a job
    running: what the panels show comes from the cache and the jobs' state, not the disk;
    a change on disk shows after a refresh (a job's end, a folder setting, the UI's timer)."""
    from .test_relit_lighting import _capture

    capture = _capture(tmp_path / "capture", lights=True)
    (capture / "frames.json").write_text('{"frames": []}')
    for folder in ("images", "masks"):
        (capture / folder).mkdir(exist_ok=True)
        (capture / folder / "0000.png").write_bytes(b"")
    run = tmp_path / "run"
    (run / "state").mkdir(parents=True)
    (run / "state" / "state.json").write_text("{}")
    (run / "command.json").write_text('{"argv": ["reconstruct", "c", "--out", "r"]}')
    sft = context.scene.sft
    sft.capture_dir, sft.run_dir, sft.lighting = str(capture), str(run), "CAPTURED"
    job = addon.jobs.ReconstructJob(sys.executable, ["reconstruct", "c", "--out", str(tmp_path / "r2"), "--steps",
                                                    "400", "--delay", "0.05"], tmp_path / "r2", "Reconstruction",
                                    root=SCRIPTED_BACKEND)
    try:
        while job.state.iteration < 2:
            job.step(context)
            time.sleep(0.02)
        names = ("SFT_PT_capture", "SFT_PT_cameras", "SFT_PT_reconstruct", "SFT_PT_reconstruct_advanced",
                 "SFT_PT_preview")
        with file_access_counted() as calls:
            logs = {name: draw(name, context) for name in names}
        assert calls == [], calls
        assert ("label", "1 frames, 1 masks") in logs["SFT_PT_capture"]
        assert ("label", "Lighting: the capture's point lights (1)") in logs["SFT_PT_reconstruct"]
        assert any(e[0] == "progress" for e in logs["SFT_PT_reconstruct"])
        (capture / "masks" / "0001.png").write_bytes(b"")
        assert ("label", "1 frames, 1 masks") in draw("SFT_PT_capture", context)  # not read while drawing
        addon.capture_state.refresh(context.scene)
        assert ("label", "1 frames, 2 masks") in draw("SFT_PT_capture", context)
    finally:
        job.process.kill()
        job.run_blocking(context, 0.02)
        addon.jobs.ACTIVE.pop("reconstruct", None)
