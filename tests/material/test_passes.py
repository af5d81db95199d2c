"""Diffuse-only and specular-only passes (Table 1's component PSNR/SSIM)."""

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.model import Frame  # noqa: E402
from backend.render.passes import ComponentField, component_renders  # noqa: E402
from backend.render.fields import ConstantField  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402


def frames(n=2, res=24):
    cams = layout.orbit_cameras(layout.fibonacci_sphere(n), np.zeros(3), 0.6, res)
    return [Frame(f"{i}", None, c, lights=layout.paper_lights(c, 2.0)) for i, c in enumerate(cams)]


def test_direct_light_passes_add_up_to_the_full_render():
    # under point lights with direct light only the BSDF is linear in its two lobes
    mesh = procedural.blob(2)
    out = component_renders(mesh, ConstantField([0.6, 0.3, 0.2], 0.5, 0.3), frames(), spp=8, max_depth=2)
    for full, diffuse, specular in zip(out["full"], out["diffuse"], out["specular"]):
        assert full.max() > 0.05 and specular.max() > 0.01 and diffuse.max() > 0.05
        np.testing.assert_allclose(diffuse + specular, full, atol=1e-4)
        # the specular lobe is grey: its pass carries no colour, the diffuse pass is red-tinted
        np.testing.assert_allclose(specular[..., 0], specular[..., 2], atol=1e-5)
        assert diffuse[..., 0].sum() > 2 * diffuse[..., 2].sum()


def test_specular_pass_is_black_without_a_specular_lobe():
    mesh = procedural.blob(2)
    out = component_renders(mesh, ConstantField(0.6, 0.0, 0.3), frames(1), spp=4, max_depth=3,
                            components=("specular", "diffuse"))
    assert set(out) == {"specular", "diffuse"}
    assert np.abs(out["specular"][0]).max() == 0.0 and out["diffuse"][0].max() > 0.05


def test_component_field_names_the_lobe_it_keeps():
    with pytest.raises(ValueError, match="keep"):
        ComponentField(ConstantField(0.5, 0.1, 0.5), "glossy")
