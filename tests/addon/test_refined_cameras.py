"""Relit Preview's cameras after ``reconstruct --refine-cameras`` (addon/io/capture_file.py) and
the panel's line from the ``cameras`` event (addon/io/progress.py), bpy-free."""

from __future__ import annotations

import json

import numpy as np
import pytest

from addon.io import capture_file, progress
from addon.io.errors import AddonInputError
from backend import fsio
from backend.capture.load import load_capture
from backend.optimize import camera_fit as cf


def test_relit_preview_takes_the_run_s_refined_cameras(tiny_capture, tmp_path):
    capture = load_capture(tiny_capture)
    fit = cf.CameraFit([f.name for f in capture.frames], [f.camera for f in capture.frames], np.zeros(3))
    fit.correction.omega[1] = [0.0, np.radians(0.5), 0.0]
    fit.correction.dolly[2] = 0.01
    run = tmp_path / "run"
    run.mkdir()
    info = capture_file.read_capture(tiny_capture)
    assert capture_file.with_refined_cameras(info, run) is info  # no cameras.json: the capture's
    fsio.write_json(run / cf.FILENAME, fit.cameras_json())
    refined = capture_file.with_refined_cameras(info, run)
    moved = fit.cameras()
    for i in range(len(info.frames)):
        np.testing.assert_allclose(refined.frames[i].camera.matrix_world, moved[i].camera_to_world, atol=1e-12)
    assert not np.allclose(refined.frames[1].camera.matrix_world, info.frames[1].camera.matrix_world)
    np.testing.assert_array_equal(refined.frames[0].camera.matrix_world, info.frames[0].camera.matrix_world)

    doc = json.loads((run / cf.FILENAME).read_text())
    doc["frames"][0]["camera"]["camera_to_world"][0][3] = float("nan")
    (run / cf.FILENAME).write_text(json.dumps(doc))
    with pytest.raises(AddonInputError, match="NaN"):
        capture_file.with_refined_cameras(info, run)


def test_the_panel_line_reads_the_cameras_event():
    state = progress.RunState()
    state.update({"event": "cameras", "level": 1, "reprojection_px": 0.42, "rotation_deg": 0.12,
                  "translation_pct": 0.3, "diverged": False})
    assert state.refined_cameras == "cameras refined: 0.42 px (0.12\u00b0, 0.3 %)"
    state.update({"event": "cameras", "level": 2, "reprojection_px": 0.0, "diverged": True})
    assert "diverged" in state.refined_cameras
