"""The add-on's bpy-free layer (addon/io): PLY reading, environment and camera conventions,
frames, the preset file, run state and interpreter choice; and that the layer imports
without Blender."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from PIL import Image

from addon.io import capture_file, envmap, frames, interpreter, preset_file, progress
from addon.io.errors import AddonInputError
from addon.io.files import png_bytes, replace_dir, write_atomic
from addon.io.ply import read_display_mesh
from backend.geometry.mesh import Mesh, save_mesh


def test_display_mesh_roundtrip_with_backend_writer(tmp_path):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(50, 3))
    f = rng.integers(0, 50, size=(80, 3))
    cols = rng.random((50, 3)).astype(np.float32)
    spec, rough = rng.random(50).astype(np.float32), rng.random(50).astype(np.float32)
    normals = rng.normal(size=(50, 3)).astype(np.float32)
    save_mesh(tmp_path / "m.ply", Mesh(v, f, cols, {"specular": spec, "roughness": rough,
                                                    **dict(zip(("nx", "ny", "nz"), normals.T))}))
    dm = read_display_mesh(tmp_path / "m.ply")
    assert dm.vertices.dtype == np.float32 and dm.faces.dtype == np.int32
    np.testing.assert_allclose(dm.vertices, v.astype(np.float32))
    np.testing.assert_array_equal(dm.faces, f)
    np.testing.assert_array_equal(dm.colors, cols)
    np.testing.assert_array_equal(dm.attributes["specular"], spec)
    np.testing.assert_array_equal(dm.attributes["roughness"], rough)
    np.testing.assert_array_equal(dm.normals, normals)
    assert set(dm.attributes) == {"specular", "roughness"}


def test_display_mesh_rejects_bad_files(tmp_path):
    save_mesh(tmp_path / "m.ply", Mesh(np.eye(3), [[0, 1, 2]]))
    data = (tmp_path / "m.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-5])
    (tmp_path / "text.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    (tmp_path / "junk.ply").write_bytes(b"\x00\x01garbage")
    for name, words in [("cut.ply", "truncated"), ("text.ply", "binary"), ("junk.ply", "not a PLY"),
                        ("missing.ply", "cannot read")]:
        with pytest.raises(AddonInputError, match=words) as err:
            read_display_mesh(tmp_path / name)
        assert name in str(err.value) and "Fix:" in str(err.value)


@pytest.mark.parametrize("rotation", [0.0, 30.0, -75.0])
def test_envmap_convention(rotation):
    # the documented formula, written out independently
    for d in np.random.default_rng(1).normal(size=(20, 3)):
        d /= np.linalg.norm(d)
        a = math.radians(rotation)
        dr = np.array([math.cos(a) * d[0] - math.sin(a) * d[1], math.sin(a) * d[0] + math.cos(a) * d[1], d[2]])
        u, v = envmap.direction_to_uv(d, rotation)
        assert u == pytest.approx((0.5 - math.atan2(dr[1], dr[0]) / (2 * math.pi)) % 1.0)
        assert v == pytest.approx(math.acos(dr[2]) / math.pi)
        np.testing.assert_allclose(envmap.uv_to_direction(u, v, rotation), d, atol=1e-12)
    # +X is the image centre, +Z its top, +Y a quarter to the left
    assert envmap.direction_to_uv([1, 0, 0]) == pytest.approx((0.5, 0.5))
    assert envmap.direction_to_uv([0, 0, 1])[1] == pytest.approx(0.0)
    assert envmap.direction_to_uv([0, 1, 0]) == pytest.approx((0.25, 0.5))


def _cam(**over):
    cam = {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 24.0,
           "camera_to_world": np.eye(4).tolist()}
    cam.update(over)
    return cam


def test_blender_camera_intrinsics():
    c = capture_file.blender_camera(_cam())
    assert c.lens == pytest.approx(50 / 64 * 36) and c.sensor_width == 36
    assert (c.shift_x, c.shift_y, c.pixel_aspect) == (0.0, 0.0, 1.0)
    c = capture_file.blender_camera(_cam(cx=40.0, cy=20.0, fy=60.0))
    assert c.shift_x == pytest.approx(-8 / 64)  # principal point right of centre: window shifts left
    assert c.shift_y == pytest.approx(-4 / 64 * 50 / 60)  # principal point above centre
    assert c.pixel_aspect == pytest.approx(1.2)


@pytest.mark.parametrize("change, words", [
    ({"fx": -1.0}, "positive"), ({"camera_to_world": [[float("nan")] * 4] * 4}, "NaN"),
    ({"camera_to_world": (np.eye(4) * [1, 2, 1, 1]).tolist()}, "orthogonal"),
    ({"camera_to_world": [[1, 0], [0, 1]]}, "4x4"), ({"fy": "x"}, "numbers")])
def test_blender_camera_rejects_bad_cameras(change, words):
    with pytest.raises(AddonInputError, match=words):
        capture_file.blender_camera(_cam(**change), "capture.json", "frame 0")


def test_read_capture(tmp_path):
    doc = {"format": capture_file.FORMAT, "version": 1,
           "frames": [{"name": "a", "image": "images/a.png", "mask": "masks/a.png", "camera": _cam(),
                       "lights": [{"type": "point", "position": [0, 0, 3], "intensity_w_per_sr": [1, 2, 3]}]}],
           "environment": {"path": "env.exr", "strength": 2.0, "rotation_z_deg": 15}}
    (tmp_path / "capture.json").write_text(json.dumps(doc))
    info = capture_file.read_capture(tmp_path)
    assert info.frames[0].image == tmp_path / "images/a.png" and info.frames[0].mask == tmp_path / "masks/a.png"
    assert info.frames[0].lights[0]["intensity_w_per_sr"] == [1, 2, 3]
    assert info.environment == {"path": tmp_path / "env.exr", "strength": 2.0, "rotation_z_deg": 15.0}
    (tmp_path / "capture.json").write_text("{broken")
    with pytest.raises(AddonInputError, match="invalid JSON"):
        capture_file.read_capture(tmp_path)
    with pytest.raises(AddonInputError, match="capture not found"):
        capture_file.read_capture(tmp_path / "nowhere")


def test_pick_frames_and_blur():
    assert frames.pick_frames(10, every_nth=3) == [0, 3, 6, 9]
    assert frames.pick_frames(100, target_count=5) == [0, 25, 50, 74, 99]
    assert frames.pick_frames(4, target_count=10) == [0, 1, 2, 3]
    rng = np.random.default_rng(2)
    sharp = rng.random((40, 40))
    k = np.ones(5) / 5
    blurred = np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 0,
                                  np.apply_along_axis(lambda r: np.convolve(r, k, "same"), 1, sharp))
    scores = [frames.sharpness(sharp), frames.sharpness(blurred), frames.sharpness(sharp * 0.9)]
    assert scores[1] < 0.2 * scores[0]
    assert frames.sharp_enough(scores, 0.3) == [True, False, True]
    assert frames.sharp_enough(scores, 0.0) == [True, True, True]


def test_match_masks():
    assert frames.match_masks(3, [0, 10, 20], 30, "m") == [0, 1, 2]
    assert frames.match_masks(30, [0, 10, 20], 30, "m") == [0, 10, 20]
    with pytest.raises(AddonInputError, match="7 masks match neither the 3 frames nor the 30"):
        frames.match_masks(7, [0, 10, 20], 30, "masks/")


def test_mask_from_rgba():
    rgba = np.zeros((2, 2, 4), np.float32)
    rgba[..., 3] = 1
    rgba[0, 0, :3] = 1
    assert frames.mask_from_rgba(rgba).tolist() == [[255, 0], [0, 0]]
    rgba[..., :3] = 1
    rgba[..., 3] = [[0, 1], [1, 0]]  # alpha carries the mask
    assert frames.mask_from_rgba(rgba).tolist() == [[0, 255], [255, 0]]


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 3), (5, 7, 4)])
def test_png_bytes_decode_exactly(tmp_path, shape):
    pixels = np.random.default_rng(3).integers(0, 256, size=shape, dtype=np.uint8)
    write_atomic(tmp_path / "p.png", png_bytes(pixels))
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "p.png")), pixels)
    assert [p.name for p in tmp_path.iterdir()] == ["p.png"]


def test_replace_dir(tmp_path):
    (tmp_path / "dst").mkdir()
    (tmp_path / "dst" / "old").write_text("old")
    (tmp_path / "new").mkdir()
    (tmp_path / "new" / "fresh").write_text("new")
    replace_dir(tmp_path / "new", tmp_path / "dst")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dst"]
    assert [p.name for p in (tmp_path / "dst").iterdir()] == ["fresh"]


def test_image_sequence_natural_order(tmp_path):
    for name in ["m10.png", "m2.png", "m1.png", "notes.txt"]:
        (tmp_path / name).write_bytes(b"")
    assert [p.name for p in frames.image_sequence(tmp_path / "m2.png")] == ["m1.png", "m2.png", "m10.png"]
    (tmp_path / "empty").mkdir()
    with pytest.raises(AddonInputError, match="no images"):
        frames.image_sequence(tmp_path / "empty")
    with pytest.raises(AddonInputError, match="folder not found"):
        frames.image_sequence(tmp_path / "missing" / "x.png")


def test_presets_calibration(tmp_path):
    assert preset_file.calibration(tmp_path) == {}
    assert preset_file.describe("draft", {}) == "not calibrated"
    (tmp_path / "backend").mkdir()
    (tmp_path / "backend" / "presets.json").write_text(json.dumps(
        {"machine": "2-core CI", "presets": {"draft": {"expected_minutes": 3.5, "expected_f1": 0.812}}}))
    calib = preset_file.calibration(tmp_path)
    assert preset_file.describe("draft", calib) == "~3.5 min, F1 0.81 on 2-core CI"
    assert preset_file.describe("final", calib) == "not calibrated"
    # an HDR-lit capture is shown its own kind's figures, else the point-lit ones with a warning
    assert preset_file.kind_for("ESTIMATE") == preset_file.kind_for("RIG") == "environment"
    assert preset_file.kind_for("CAPTURED", "/maps/studio.hdr") == "environment"
    assert preset_file.kind_for("CAPTURED") == preset_file.kind_for("FLASH", "/maps/studio.hdr") == "point"
    entries, note = preset_file.kind_calibration(calib, "environment")
    assert entries is calib and note.endswith("HDR-lit captures take longer")
    calib["kinds"] = {"point": {"presets": calib["presets"]},
                      "environment": {"presets": {"draft": {"expected_minutes": 4.8, "expected_f1": 0.97},
                                                  "final": {"expected_minutes": 9.0, "expected_f1": 0.96,
                                                            "dominated_by": "draft"}}}}
    entries, note = preset_file.kind_calibration(calib, "environment")
    assert preset_file.describe("draft", entries) == "~4.8 min, F1 0.97 on 2-core CI"
    # a preset a cheaper one matched on that kind's scene says it buys nothing there
    assert preset_file.describe("final", entries) == "~9 min, F1 0.96 (no gain over Draft) on 2-core CI"
    assert note == "Times measured on an HDR-lit object"
    entries, note = preset_file.kind_calibration(calib, "point")
    assert preset_file.describe("draft", entries) == "~3.5 min, F1 0.81 on 2-core CI"
    assert note == "Times measured on a point-lit object"
    (tmp_path / "backend" / "presets.json").write_text("{not json")
    assert preset_file.calibration(tmp_path) == {}



def test_preset_list_comes_from_the_preset_file(tmp_path):
    # the shipped file names the Quality enum's items, in its order
    shipped = json.loads((interpreter.PACKAGE_DIR / "backend" / "presets.json").read_text())
    assert [key for key, _, _ in preset_file.PRESETS] == list(shipped["presets"])
    assert [label for _, label, _ in preset_file.PRESETS] == [k.capitalize() for k in shipped["presets"]]
    (tmp_path / "backend").mkdir()
    (tmp_path / "backend" / "presets.json").write_text(json.dumps(
        {"presets": {"balanced": {"expected_minutes": 12.0}, "draft": {}},
         "kinds": {"environment": {"presets": {"draft": {}, "sketch": {"expected_minutes": 0.5}}}}}))
    items = preset_file.enum_items(preset_file.calibration(tmp_path))
    assert [key for key, _, _ in items] == ["balanced", "draft", "sketch"]  # a kind's own preset comes last
    assert items[1] == ("draft", "Draft", preset_file.DESCRIPTIONS["draft"])
    assert items[2][1:] == ("Sketch", "The backend's Sketch preset")
    # without a readable file: the same names as the backend's, with their tooltips
    (tmp_path / "backend" / "presets.json").unlink()
    assert [key for key, _, _ in preset_file.enum_items(preset_file.calibration(tmp_path))] == [
        "draft", "balanced", "final"]
    assert preset_file.preset_names({"presets": {}}) == preset_file.FALLBACK_NAMES


def test_io_layer_imports_without_blender():
    """Every module of addon/io imports in a Python where bpy (and Mitsuba) cannot be imported."""
    folder = interpreter.PACKAGE_DIR / "addon" / "io"
    modules = sorted(p.stem for p in folder.glob("*.py") if p.stem != "__init__")
    assert {"interpreter", "process", "progress", "ply", "preset_file", "install_backend"} <= set(modules)
    script = (
        "import importlib, json, sys\n"
        "for name in ('bpy', 'bpy_extras', 'mathutils', 'mitsuba', 'drjit'):\n"
        "    sys.modules[name] = None  # import raises ImportError\n"
        f"for name in {modules!r}:\n"
        "    importlib.import_module('addon.io.' + name)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] == 'addon')))\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                          cwd=interpreter.PACKAGE_DIR, env=interpreter.environment())
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert set(loaded) == {"addon", "addon.io", *(f"addon.io.{m}" for m in modules)}, "only the io layer loads"

def test_run_state_follows_events():
    state = progress.RunState()
    assert state.active and state.eta() is None
    state.update({"event": "variant", "variant": "llvm_ad_rgb"})
    state.update({"event": "stage", "stage": "geometry", "level": 1, "faces": 500})
    state.update({"event": "progress", "stage": "geometry", "level": 1, "iteration": 10, "iterations": 40,
                  "loss": 0.0123, "faces": 500, "fraction": 0.25, "eta_s": 30.0})
    assert state.status == progress.RUNNING and state.fraction == 0.25
    assert state.eta(time.monotonic()) == pytest.approx(30.0, abs=0.5)
    assert state.headline() == "geometry (level 1)  it 10/40  loss 0.0123"
    assert state.eta_text(state._eta_at + 12.0) == "ETA 18s"  # the estimate ages
    assert state.plan_text() == ""  # no plan yet
    state.update({"event": "preset", "preset": "draft", "predicted_minutes": 3.0, "predicted_psnr": 24.2,
                  "psnr_spread": 2.6})
    now = state._eta_at + 12.0
    assert state.predicted == "24 \u00b1 3 dB"
    assert state.plan_text(now) == f"Planned 3m 00s; now {progress.format_duration(state.elapsed(now) + 18.0)} in all"
    state.update({"event": "snapshot", "path": "snapshots/000010.ply", "iteration": 10, "faces": 500, "loss": 0.01})
    assert state.snapshot == "snapshots/000010.ply" and state.snapshots == 1
    state.update({"event": "done", "result": "result.ply", "report": "report.json", "metrics": {"f1": 0.9}})
    assert state.status == progress.DONE and not state.active and state.fraction == 1.0
    assert state.headline() == "Done"


def test_the_predicted_psnr_is_shown_beside_the_held_out_scores():
    state = progress.RunState()
    state.update({"event": "preset", "preset": "draft", "predicted_psnr": 23.81, "psnr_spread": 3.24})
    state.update({"event": "accuracy", "seconds": 5.0, "psnr": 20.5})
    state.update({"event": "accuracy", "seconds": 65.0, "psnr": 23.1})
    assert state.accuracy_text() == "Held-out PSNR 23.1 dB (+2.6 dB in 1m 00s, 2 scores; predicted 24 \u00b1 3 dB)"
    finer = progress.RunState()  # scored finer than the calibration captures: a floor
    finer.update({"event": "preset", "preset": "balanced", "predicted_psnr": 20.9, "psnr_spread": None,
                  "psnr_extrapolated": "finer"})
    assert finer.predicted == "21+ dB"
    resumed = progress.RunState()  # a resumed run's preset event predicts nothing
    resumed.update({"event": "preset", "preset": "draft", "predicted_psnr": None})
    resumed.update({"event": "accuracy", "seconds": 1.0, "psnr": 20.0})
    assert "predicted" not in resumed.accuracy_text()


def test_run_state_eta_without_backend_estimate():
    state = progress.RunState(started=time.monotonic() - 10.0)
    state.update({"event": "progress", "fraction": 0.25})
    assert state.eta() == pytest.approx(30.0, abs=0.5)


def test_run_state_settles_crash_and_cancel():
    crashed = progress.RunState()
    crashed.finish(1, "Traceback ... | RuntimeError: boom")
    assert crashed.status == progress.FAILED and "RuntimeError: boom" in crashed.message
    assert crashed.headline().startswith("Failed: the backend exited with code 1; log: Traceback")
    cancelled = progress.RunState()
    cancelled.finish(130)
    assert cancelled.status == progress.CANCELLED
    failed = progress.RunState()
    failed.update({"event": "error", "message": "capture.json: no frames"})
    failed.finish(2, "error: ignored because the event said it")
    assert failed.message == "capture.json: no frames"
    bad = progress.RunState()
    bad.finish(2, "loading | error: x/capture.json: capture has no frames. Fix: add frames")
    assert bad.status == progress.FAILED and bad.message == "x/capture.json: capture has no frames. Fix: add frames"


def test_format_duration():
    assert [progress.format_duration(s) for s in (5, 65, 3725)] == ["5s", "1m 05s", "1h 02m"]


def test_default_python_order(tmp_path, monkeypatch):
    monkeypatch.setenv("SFT_PYTHON", "/opt/sft/bin/python")
    assert interpreter.default_python(tmp_path) == "/opt/sft/bin/python"
    venv = tmp_path / ".venv" / "bin"
    venv.mkdir(parents=True)
    (venv / "python").write_text("")
    assert interpreter.default_python(tmp_path) == str(venv / "python")
    monkeypatch.delenv("SFT_PYTHON")
    assert interpreter.default_python(tmp_path / "elsewhere") and "SFT" not in interpreter.default_python(tmp_path / "x")
    # a developer .venv counts as set up even when it is activated (its python is the PATH's)
    monkeypatch.setenv("PATH", str(venv) + os.pathsep + os.environ.get("PATH", ""))
    (venv / "python3").write_text("")
    for exe in (venv / "python", venv / "python3"):
        exe.chmod(0o755)
    assert interpreter.has_interpreter(tmp_path) and not interpreter.has_interpreter(tmp_path / "x")


def test_backend_command_discovery():
    assert interpreter.has_command("check") and interpreter.has_command("synth")
    assert not interpreter.has_command("no-such-command")
    env = interpreter.environment()
    assert env["PYTHONPATH"].split(os.pathsep)[0] == str(interpreter.PACKAGE_DIR)


def test_check_reports_real_interpreter(tmp_path):
    ok = interpreter.check(sys.executable)
    assert ok.ok and ok.summary.startswith("OK") and "mitsuba" in ok.summary
    missing = interpreter.check(str(tmp_path / "no-python"))
    assert not missing.ok and "interpreter not found" in missing.summary


def test_effects_event_is_summarised_for_the_panel():
    state = progress.RunState()
    state.update({"event": "effects", "enabled": {"max_depth": 2, "shadows": False, "specular": True}})
    assert state.effects == "direct light, specular"
    state.update({"event": "effects", "enabled": {"max_depth": 4, "shadows": True, "specular": False}})
    assert state.effects == "3 bounces, shadows, diffuse only"
    state.update({"event": "shadow_samples", "level": 1, "full": 12, "chosen": 7, "measured_ratio": 2.38,
                  "expected_ratio": 1.804})
    assert state.shadow_samples == "shadows: 7 samples/px, 1.8x a step"
    # the level's own steps at that count, timed: the measured ratio replaces the prediction
    state.update({"event": "shadow_samples", "level": 1, "full": 12, "chosen": 7, "measured_ratio": 2.38,
                  "expected_ratio": 1.804, "checked": True, "achieved_ratio": 1.93})
    assert state.shadow_samples == "shadows: 7 samples/px, 1.9x a step, measured"
    state.update({"event": "effects", "enabled": {"max_depth": 3, "shadows": False, "specular": True}})
    assert state.shadow_samples == ""  # shadow gradients off: no cost line
    state.update({"event": "stiffness", "lambda": 20.0, "clip": 99.5, "chroma_spread": 0.15,
                  "reason": "a constant material cannot explain the frames' colour variation"})
    assert state.smoothing == "λ 20 (textured, one constant material)"


def test_lighting_events_are_summarised_for_the_panel():
    state = progress.RunState()
    assert state.lighting == ""  # a captured map: no lighting events, no line
    base = {"event": "lighting", "model": "estimate", "frame": "world", "resolution": [16, 8]}
    state.update(dict(base, when="initial", stage=None))
    assert state.lighting == "estimated map 16x8, first guess"
    state.update(dict(base, when="fitted", stage="diffuse", resolution=[32, 16]))
    assert state.lighting == "estimated map 32x16, fitted (diffuse)"
    state.update(dict(base, when="restarted", stage=None, frame="camera"))
    assert state.lighting == "map on the camera rig 16x8, fitting again on the final surface"
    state.update(dict(base, when="relit", stage=None))
    assert state.lighting == "estimated map 16x8, fitted again on the final surface"
    state.update(dict(base, when="restored", stage=None))
    assert state.lighting.endswith("the fit before the final surface kept (the refit fitted the views worse)")
    state.update(dict(base, when="fitted", stage="constant", frame="world+camera"))
    assert state.lighting == "world map + camera rig map 16x8, fitted (constant)"
    state.update({"event": "lighting", "model": "flash", "when": "fitted", "stage": "constant", "intensity": 2.0})
    assert state.lighting == "flash, fitted (constant)"


def test_solved_cameras_are_summarised_with_the_silhouette_refinement():
    done = {"event": "done", "registered": 40, "total": 40, "reprojection_error_px": 0.5186,
            "silhouettes": {"applied": True, "frames": 37, "pairs": 312, "dropped": ["00012"]}}
    assert progress.cameras_summary(done) == ("40/40 frames registered (0.52 px), refined by 37 silhouettes "
                                              "(masks left out: 00012)")
    done["silhouettes"] = {"applied": False, "frames": 2, "reason": "2 frames with silhouettes"}
    assert progress.cameras_summary(done).endswith("silhouettes not used: 2 frames with silhouettes")
    assert progress.cameras_summary({"event": "done"}) == ""  # a reconstruct run's done event
