"""The relight on the final surface (backend/optimize/relight.py), judged with real renders: a
relit fit that renders the views as well is kept; one that lost them gives the earlier
material and lighting back, value for value."""

from __future__ import annotations

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.load import load_capture  # noqa: E402
from backend.geometry.init import initial_mesh  # noqa: E402
from backend.material.schedule import restore_values, saved_values  # noqa: E402
from backend.optimize import relight  # noqa: E402
from backend.optimize.appearance import Appearance  # noqa: E402
from backend.optimize.config import ReconstructConfig  # noqa: E402
from backend.optimize.views import ViewSet  # noqa: E402
from tests.helpers import shared_data, withheld_map_capture  # noqa: E402


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """An appearance with an estimated map, its material fitted through the constant stage on
    the carved surface of a capture rendered under the forest map (withheld)."""
    root = tmp_path_factory.mktemp("relight")
    dark, _ = withheld_map_capture(root, 6, 24, 16, shared_data("envmaps", "forest_slope_1k.hdr"))
    capture = load_capture(dark)
    config = ReconstructConfig(material="staged", lighting="estimate", spp=4, max_size=24, coarse_size=24,
                               initial_faces=400)
    appearance = Appearance(capture, config, emit=lambda *a, **k: {})
    appearance.start_lighting(root)
    mesh, _ = initial_mesh(capture, None, config.initial_faces)
    views = ViewSet(capture, config.max_size).at(config.max_size)
    material = appearance.initial_material(mesh, views)
    appearance.light_first(mesh, material, views)
    return appearance, mesh, material, views


def test_a_relight_that_lost_the_views_gives_the_earlier_fit_back(fitted):
    appearance, mesh, material, views = fitted
    albedo, latent = material.values("albedo").copy(), appearance.lighting.latent.copy()
    judge = relight.Relight()
    judge.start(appearance, mesh, material, views)
    assert appearance.lighting.restarts == 1 and appearance.driver.stage == "constant"
    assert not np.allclose(material.values("albedo"), albedo)  # back to neutral grey
    material.set_values("albedo", np.full_like(material.values("albedo"), 0.02))  # a fit that lost the views
    record = judge.judge(appearance, mesh, material)
    assert not record["kept"] and record["loss_after"] > relight.TOLERANCE * record["loss_before"]
    assert np.allclose(material.values("albedo"), albedo)
    assert np.array_equal(appearance.lighting.latent, latent)
    assert judge.judge(appearance, mesh, material) is None  # judged once


def test_a_relight_that_fits_as_well_is_kept(fitted):
    appearance, mesh, material, views = fitted
    values, latent = saved_values(material), appearance.lighting.latent.copy()
    judge = relight.Relight()
    judge.start(appearance, mesh, material, views)
    restore_values(material, values)  # the relit fit came back to where the earlier one was
    appearance.lighting.latent = latent
    appearance.capture.environment = appearance.lighting.environment()
    record = judge.judge(appearance, mesh, material)
    assert record["kept"] and record["loss_after"] == pytest.approx(record["loss_before"], rel=1e-3)


def test_a_map_on_the_camera_rig_is_not_relit(fitted):
    """Fresh fits under a map fixed to the camera lose the views, so the final stages go on
    from the fit the levels made."""
    appearance, mesh, material, views = fitted
    albedo, restarts = material.values("albedo").copy(), appearance.lighting.restarts
    appearance.lighting.frame = "camera"
    try:
        appearance.finalise(mesh, material, views)
        assert appearance.relight.saved is None and appearance.lighting.restarts == restarts
        assert appearance.driver.schedule.final and np.array_equal(material.values("albedo"), albedo)
    finally:
        appearance.lighting.frame = "world"
