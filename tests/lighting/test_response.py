"""The camera response block is what the reconstruction's targets are divided by."""

from __future__ import annotations

import numpy as np

from backend.capture import CameraResponse, load_capture, save_capture
from backend.capture.images import read_linear_rgb
from backend.optimize.views import ViewSet
from tests.capture.test_import_command import make_capture


def test_targets_are_frames_over_exposure_and_white_balance(tmp_path):
    folder = make_capture(tmp_path / "capture")
    plain = ViewSet(load_capture(folder), 64)
    capture = load_capture(folder)
    capture.camera_response = CameraResponse(0.5, (1.25, 1.0, 0.8), "srgb", "estimated")
    save_capture(capture)
    reloaded = load_capture(folder)
    assert reloaded.camera_response == capture.camera_response
    views = ViewSet(reloaded, 64)
    for a, b, frame in zip(plain.views, views.views, reloaded.frames):
        assert a.target.max() > 0
        np.testing.assert_allclose(b.target, a.target / (0.5 * np.array([1.25, 1.0, 0.8])), rtol=1e-5)
        mask = a.mask > 0.5
        np.testing.assert_allclose(a.target[mask], read_linear_rgb(frame.image)[mask] * a.mask[mask, None], rtol=1e-5)
