"""End to end with the real backend: `python -m backend reconstruct` in a subprocess,
streaming into Blender, cancel, resume, and the headless script."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from importlib import import_module

import bpy
import numpy as np
import pytest
from PIL import Image

from backend import fsio
from backend.geometry.mesh import save_mesh, load_mesh

from .conftest import REPO

SCRIPT = REPO / "scripts" / "reconstruct.py"
TINY = "--iterations 12 --max-size 32 --coarse-size 32 --initial-faces 300"  # seconds, not minutes


def _arrays(obj):
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.attributes["position"].data.foreach_get("vector", co)
    colors = me.color_attributes.get("albedo")
    col = np.empty(len(me.vertices) * 4, np.float32)
    if colors is not None:
        colors.data.foreach_get("color", col)
    return co.reshape(-1, 3), col.reshape(-1, 4)[:, :3]


def _job(addon, extension, capture, run):
    args = import_module(f"{extension.__name__}.addon.operators.reconstruct").reconstruct_args(
        capture, run, None, TINY)
    return addon.jobs.ReconstructJob(sys.executable, args, run, "Reconstruction")


def _cancel_after_first_snapshot(context, job):
    start = time.monotonic()
    while job.applied is None:
        assert job.step(context), f"finished before a snapshot: {job.state.message}"
        assert time.monotonic() - start < 300
        time.sleep(0.1)
    job.stop()
    job.run_blocking(context)


def test_real_reconstruction_streams_mesh_and_colours(context, addon, extension, tiny_capture, tmp_path):
    job = _job(addon, extension, tiny_capture, tmp_path / "run")
    shown, start = [], time.monotonic()
    while job.step(context):  # what the modal timer does
        if job.applied and (not shown or shown[-1][0] != job.applied):
            shown.append((job.applied, *_arrays(bpy.data.objects["Reconstruction"])))
        assert time.monotonic() - start < 600, "reconstruction did not finish in 10 minutes"
        time.sleep(0.1)
    assert job.state.status == "done", job.state.message
    assert len(shown) >= 2, "fewer than two snapshots reached the scene"
    _, first_co, first_col = shown[0]
    last_co, last_col = _arrays(bpy.data.objects["Reconstruction"])
    assert first_co.shape != last_co.shape or np.abs(first_co - last_co).max() > 1e-4, "vertices never changed"
    assert first_col.shape != last_col.shape or np.abs(first_col - last_col).max() > 1e-4, "colours never changed"
    assert max(job.apply_seconds) < 0.05
    assert (tmp_path / "run" / "result.ply").is_file()


def test_reconstruct_operator_runs_headless_path(context, tiny_capture, tmp_path):
    sft = context.scene.sft
    sft.capture_dir, sft.preset, sft.extra_args = str(tiny_capture), "draft", TINY
    sft.track_accuracy = True
    assert bpy.ops.sft.reconstruct(run_dir=str(tmp_path / "run")) == {"FINISHED"}
    assert sft.run_dir == str(tmp_path / "run")
    assert len(bpy.data.objects["Reconstruction"].data.polygons) > 0
    # Track Accuracy on: the capture's ground-truth held-out views were scored
    series = json.loads((tmp_path / "run" / "report.json").read_text())["accuracy_time"]
    assert series["source"] == "ground truth" and series["points"]
    assert (tmp_path / "run" / "accuracy_time.png").is_file()


def test_cancel_keeps_last_snapshot(context, addon, extension, tiny_capture, tmp_path):
    run = tmp_path / "run"
    job = _job(addon, extension, tiny_capture, run)
    _cancel_after_first_snapshot(context, job)
    assert job.state.status == "cancelled" and job.process.returncode == 130
    snapshot = json.loads((run / "snapshot.json").read_text())
    assert (run / snapshot["mesh"]).is_file() and (run / "STOP").exists()
    assert len(bpy.data.objects["Reconstruction"].data.polygons) > 0
    assert job.process.events[-1]["event"] == "cancelled"


def test_resume_continues_a_cancelled_run_with_its_options(context, addon, extension, tiny_capture, tmp_path):
    """Resume (the panel's button) continues a cancelled run from its last snapshot with the
    command line it started with (RUN/command.json), and is offered only while unfinished."""
    run = tmp_path / "run"
    job = _job(addon, extension, tiny_capture, run)
    _cancel_after_first_snapshot(context, job)
    assert job.state.status == "cancelled"
    context.scene.sft.run_dir = str(run)
    resumable = import_module(f"{extension.__name__}.addon.operators.reconstruct").resumable
    assert resumable(str(run))
    assert bpy.ops.sft.reconstruct_resume() == {"FINISHED"}
    assert (run / "result.ply").is_file() and not (run / "STOP").exists()
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    starts = [e["settings"] for e in events if e["event"] == "start"]
    assert len(starts) == 2 and starts[0] == starts[1], "the resumed run changed its options"
    assert any(e["event"] == "stage" and e["stage"] == "resume" for e in events)
    assert events[-1]["event"] == "done"
    assert not resumable(str(run)), "a finished run is still offered for resuming"


def test_resume_refuses_a_folder_without_a_run(context, tmp_path):
    (tmp_path / "state").mkdir()
    (tmp_path / "state" / "state.json").write_text("{}")
    with pytest.raises(RuntimeError, match="cannot read the run's command line"):
        bpy.ops.sft.reconstruct_resume(run_dir=str(tmp_path))
    with pytest.raises(RuntimeError, match="nothing to resume"):
        bpy.ops.sft.reconstruct_resume(run_dir=str(tmp_path / "empty"))


def _headless(*args, timeout=600):
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


def _blend_summary(path):
    code = ("import bpy, json, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); "
            "o = bpy.data.objects.get('Reconstruction'); "
            "print(json.dumps({'faces': len(o.data.polygons) if o else 0, "
            "'cameras': len(bpy.data.cameras), 'capture': bpy.context.scene.sft.capture_dir "
            "if hasattr(bpy.context.scene, 'sft') else None, 'preview': 'SfT Relit Preview' in bpy.data.images}))")
    proc = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_headless_script_full_pipeline(tiny_capture, tmp_path):
    out = tmp_path / "scene.blend"
    proc = _headless("--", tiny_capture, "--out", out, "--preset", "draft", "--run", tmp_path / "run",
                     "--extra", TINY, "--samples", 4, "--percentage", 100)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert out.is_file() and _blend_summary(out)["faces"] > 0
    preview = np.asarray(Image.open(out.with_suffix(".preview.png")))
    assert preview.std() > 0.01 * 255


def test_headless_script_from_snapshot(tiny_capture, tmp_path):
    """The headless path without the optimiser: cameras, an existing run's snapshot, a
    Cycles preview and the .blend file (plain Python with the bpy module)."""
    run = tmp_path / "run"
    save_mesh(run / "snapshots" / "000007.ply", load_mesh(tiny_capture / "gt" / "mesh.ply"))
    fsio.write_json(run / "snapshot.json", {"mesh": "snapshots/000007.ply", "iteration": 7})
    out = tmp_path / "scene.blend"
    proc = _headless("--", tiny_capture, "--out", out, "--snapshot", run, "--samples", 4, "--percentage", 100,
                     "--python", sys.executable)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = _blend_summary(out)
    assert summary["faces"] == load_mesh(tiny_capture / "gt" / "mesh.ply").n_faces
    assert summary["cameras"] == len(json.loads((tiny_capture / "capture.json").read_text())["frames"])
    preview = np.asarray(Image.open(out.with_suffix(".preview.png")).convert("RGB")).astype(float)
    h, w = preview.shape[:2]
    assert w == 2 * h and preview[:, : w // 2].std() > 5, "empty preview render"


def test_headless_script_bad_input(tmp_path):
    proc = _headless(tmp_path / "nowhere", "--out", tmp_path / "x.blend", timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("error: ") and "nowhere" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "x.blend").exists()


def test_backend_bad_input_is_one_line_and_leaves_scene(context, tmp_path):
    from .test_capture_ops import expect_error

    (tmp_path / "capture.json").write_text('{"format": "shape-from-tracing-capture", "version": 1, "frames": []}')
    context.scene.sft.extra_args = TINY
    context.scene.sft.capture_dir = str(tmp_path)
    message = expect_error(bpy.ops.sft.reconstruct, "capture.json", "reconstruction failed",
                           run_dir=str(tmp_path / "run"))
    assert "Traceback" not in message and "exited with code" not in message


def test_a_blender_object_starts_the_reconstruction(context, tiny_capture, tmp_path, monkeypatch):
    """Initialisation = Blender Object: the object's evaluated mesh (world coordinates) is the
    backend's --init; the panel's method settings reach the command line."""
    monkeypatch.setenv("SFT_RECONSTRUCT_SETTINGS", json.dumps({"iterations": 4, "max_size": 32, "coarse_size": 32,
                                                               "max_levels": 1, "validation_views": 2}))
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, radius=0.4, location=(0.05, 0.0, 0.0))
    start = context.active_object
    sft = context.scene.sft
    sft.capture_dir, sft.init, sft.material, sft.effects, sft.time_budget = (
        str(tiny_capture), "OBJECT", "CONSTANT", "ALL", 2.0)
    run = tmp_path / "run"
    assert bpy.ops.sft.reconstruct(run_dir=str(run)) == {"FINISHED"}
    argv = json.loads((run / "command.json").read_text())["argv"]
    init = argv[argv.index("--init") + 1]
    assert init.endswith(f"{start.name}.ply") and argv[argv.index("--material") + 1] == "constant"
    assert argv[argv.index("--effects") + 1] == "all" and argv[argv.index("--time-budget") + 1] == "2"
    mesh = load_mesh(init)
    assert mesh.n_faces == 2 * len(start.data.polygons) or mesh.n_faces == len(start.data.polygons)
    assert abs(mesh.vertices[:, 0].mean() - 0.05) < 1e-3, "not in world coordinates"
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert next(e for e in events if e["event"] == "start")["settings"]["init"] == init
