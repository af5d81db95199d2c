"""Sample counts of a gradient render: the primal image takes ``primal_spp`` (the sensors'
count), the backward pass keeps the integrator's ``sppc`` / ``sppp`` (real renders, tiny size)."""

import numpy as np
import pytest

from backend import variant

variant.choose()

import drjit as dr  # noqa: E402

from backend.capture.model import Camera, Environment  # noqa: E402
from backend.optimize.config import ReconstructConfig  # noqa: E402
from backend.optimize.objective import GradientRenderer  # noqa: E402
from backend.render.effects import EffectsDecision  # noqa: E402
from backend.render.fields import ConstantField  # noqa: E402
from backend.render.scene import RenderSettings  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

RES = 24


def _renderer(settings: RenderSettings) -> GradientRenderer:
    ball = procedural.icosphere(2, 0.5)
    cams = [Camera(RES, RES, 30.0, 30.0, RES / 2, RES / 2, layout.look_at([0, -3, 1], [0, 0, 0]))]
    return GradientRenderer(ball, ConstantField([0.7, 0.6, 0.5], 0.0, 0.5), cams, [[]],
                            Environment("procedural", 1.0, 0.0), settings, env_pixels=procedural.sky(32, 30.0))


def test_a_runs_primal_samples_reach_its_geometry_steps_only():
    config = ReconstructConfig(spp=8, primal_spp=40)
    geometry = RenderSettings.for_geometry(config)
    assert geometry.primal_spp == 40 and geometry.sppc == 8 and geometry.sppp == config.sppp
    decided = EffectsDecision(max_depth=3)
    assert decided.settings(geometry, geometry=True).primal_spp == 40
    assert decided.settings(geometry, geometry=False).primal_spp == 0  # material steps: one count
    assert RenderSettings.for_geometry(ReconstructConfig()).primal_spp == 0  # the default: spp


@pytest.mark.parametrize("integrator", ["prb_projective", "prb"])
def test_the_sensors_count_is_the_primal_one_only_for_projective_integrators(integrator):
    r = _renderer(RenderSettings(spp=4, max_depth=3, integrator=integrator, sppc=4, sppp=2, primal_spp=32))
    assert r.sensors[0].sampler().sample_count() == (32 if integrator == "prb_projective" else 4)


def test_the_primal_image_of_a_gradient_render_has_the_primal_samples_noise():
    """The spread between two seeds of render_split falls as 1/spp of the primal image:
    four times the samples, about a quarter of the variance (not the backward pass's count)."""
    spreads = []
    for primal in (4, 16):
        r = _renderer(RenderSettings(spp=4, max_depth=3, integrator="prb_projective", sppc=4, sppp=2,
                                     primal_spp=primal))
        with dr.suspend_grad():
            a, b = (np.array(r.render_split(0, seed=s, params=r.params)) for s in (1, 2))
        spreads.append(float(np.var(a - b)))
    assert 0.15 < spreads[1] / spreads[0] < 0.4
