"""On the final geometry the material's last stage always gets its turn: when the time left
holds one more cycle only, the run goes on to the last stage (specular) instead of another
diffuse cycle."""

from __future__ import annotations

import pytest

from backend import variant

variant.choose()

from backend.capture.load import load_capture  # noqa: E402
from backend.optimize.appearance import Appearance  # noqa: E402
from backend.optimize.config import ReconstructConfig  # noqa: E402
from backend.optimize.views import ViewSet  # noqa: E402
from backend.synth.procedural import icosphere  # noqa: E402
from tests.helpers import run_cli  # noqa: E402


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    out = tmp_path_factory.mktemp("final") / "capture"
    run_cli("synth", "--out", out, "--views", 4, "--resolution", 16, "--spp", 4, "--held-out", 0, check=True)
    return load_capture(out)


def test_hurry_goes_on_to_the_last_stage_once_on_the_final_geometry(capture):
    mesh = icosphere(2)
    views = ViewSet(capture, 16).at(16)
    appearance = Appearance(capture, ReconstructConfig(material="staged", effects="all"), lambda *a, **k: None)
    material = appearance.initial_material(mesh, views)
    appearance.decide(mesh, material, views, reason="initial mesh")
    driver = appearance.driver
    driver.schedule.report(1.0)
    driver.schedule.report(1.0)  # constants that stopped improving end early
    assert driver.stage == "diffuse"
    assert not appearance.last_stage_due()  # geometry still moves: no hurry
    appearance.hurry()
    assert driver.stage == "diffuse"
    appearance.finalise()
    assert appearance.last_stage_due()
    appearance.hurry()
    assert driver.stage == "specular" and not appearance.last_stage_due()
    result = appearance.material_cycle(mesh, material, views, level=0)
    assert result["stage"] == "specular" and result["seconds"] > 0
