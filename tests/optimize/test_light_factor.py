"""The staged material's fitted light factor k lights every later render of the capture's own
lighting: the material stages' renderers, the geometry objective and the held-out scoring."""

from __future__ import annotations

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.load import load_capture  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.optimize.appearance import Appearance, lit_environment  # noqa: E402
from backend.optimize.config import ReconstructConfig  # noqa: E402
from backend.optimize.objective import Objective  # noqa: E402
from backend.optimize.views import ViewSet  # noqa: E402
from backend.render.scene import RenderSettings  # noqa: E402
from backend.synth.procedural import icosphere  # noqa: E402
from tests.helpers import run_cli  # noqa: E402


@pytest.fixture(scope="module")
def env_capture(tmp_path_factory):
    out = tmp_path_factory.mktemp("lit") / "capture"
    run_cli("synth", "--out", out, "--views", 4, "--resolution", 16, "--spp", 4, "--held-out", 0,
            "--lighting", "env", "--env", "sky", "--env-strength", 0.8, check=True)
    return load_capture(out)


def test_renderers_after_a_light_fit_use_strength_times_k(env_capture):
    mesh = icosphere(2)
    material = MeshColorMaterial(mesh, 1, np.zeros(mesh.n_faces, np.int64), 1)
    views = ViewSet(env_capture, 16).at(16)
    strength = env_capture.environment.strength
    appearance = Appearance(env_capture, ReconstructConfig(material="staged"), lambda *a, **k: None)
    before = appearance._renderer(mesh, material, views, geometry=False)
    assert float(before.params["environment.scale"][0]) == pytest.approx(strength)
    material.light_factor = 2.0
    stages = appearance._renderer(mesh, material, views, geometry=False)
    assert float(stages.params["environment.scale"][0]) == pytest.approx(2.0 * strength)
    objective = Objective(mesh, material, views, RenderSettings(spp=2, integrator="direct_projective"),
                          lit_environment(env_capture, material))
    assert float(objective.renderer.params["environment.scale"][0]) == pytest.approx(2.0 * strength)
    assert env_capture.environment.strength == strength, "the capture itself is left as given"
