"""The fit's views (backend/optimize/views.py): a frame resampled to a level's size lines up
with a render through the scaled camera (real renders)."""

from __future__ import annotations

import numpy as np
import pytest

from backend.bench.cameras import FixedMaterial
from backend.capture.load import load_capture
from backend.geometry.mesh import load_mesh
from backend.optimize.objective import Objective
from backend.optimize.views import ViewSet
from backend.render.scene import RenderSettings


@pytest.mark.parametrize("size", [32, 24])
def test_a_resampled_frame_lines_up_with_the_render_through_the_scaled_camera(tiny_capture, size):
    """The tiny capture's 48-px frames at 32 px (1.5x) and 24 px (2x) against renders of the
    true mesh: the least-squares image shift between them (from the render's gradient) stays
    under 0.05 px, where a resampling that weighs whole pixels by their centres is 0.2 px off
    at 1.5x (and a camera refinement would move every camera to follow it)."""
    capture = load_capture(tiny_capture)
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    views = ViewSet(capture, size).at(size)
    assert max(views[0].camera.width, views[0].camera.height) == size
    settings = RenderSettings(spp=64, max_depth=2, integrator="direct_projective", sppc=16, sppp=4)
    objective = Objective(mesh, FixedMaterial(mesh), views, settings, capture.environment, tone="linear")
    shifts = []
    for i, view in enumerate(views):
        render = np.array(objective.renderer.render(i, seed=1, spp=64)).mean(-1)
        gy, gx = np.gradient(render)
        jac = np.stack([gx.ravel(), gy.ravel()], 1)
        shifts.append(np.linalg.lstsq(jac, (np.asarray(view.target).mean(-1) - render).ravel(), rcond=None)[0])
    mean = np.abs(np.mean(shifts, 0))
    assert mean.max() < 0.05, (size, mean)
