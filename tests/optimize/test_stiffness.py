"""The Large Steps stiffness is chosen from the frames' colour variation (real synthetic renders)."""

from __future__ import annotations

import pytest

from backend.capture.load import load_capture
from backend.optimize.config import ReconstructConfig
from backend.optimize.stiffness import SOFT, STIFF, TEXTURED, chroma_spread, choose
from backend.optimize.views import ViewSet
from tests.helpers import run_cli


def views_of(tmp_path_factory, albedo: str, *extra) -> list:
    out = tmp_path_factory.mktemp("stiffness") / "capture"
    run_cli("synth", "--out", out, "--views", 4, "--resolution", 48, "--spp", 16, "--held-out", 0,
            "--albedo", albedo, *extra, check=True)
    return ViewSet(load_capture(out), 48).views


@pytest.fixture(scope="module")
def uniform(tmp_path_factory):
    return views_of(tmp_path_factory, "0.6,0.4,0.3", "--specular", "0.3", "--roughness", "0.2")


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    return views_of(tmp_path_factory, "pattern")


def test_uniform_colour_with_highlights_is_soft_and_texture_is_stiff(uniform, textured):
    assert chroma_spread(uniform) < 0.5 * TEXTURED  # shading and white highlights barely change chromaticity
    assert chroma_spread(textured) > 2 * TEXTURED
    soft = choose(ReconstructConfig(), uniform, spatially_varying=False)
    stiff = choose(ReconstructConfig(), textured, spatially_varying=False)
    assert (soft.lambda_, soft.clip) == SOFT and (stiff.lambda_, stiff.clip) == STIFF
    assert stiff.event()["chroma_spread"] > TEXTURED and "constant material" in stiff.reason


def test_mesh_colors_keep_the_soft_system_and_given_values_win(textured):
    assert (choose(ReconstructConfig(), textured, spatially_varying=True).lambda_) == SOFT[0]
    given = choose(ReconstructConfig(lambda_=7.0), textured, spatially_varying=False)
    assert (given.lambda_, given.clip) == (7.0, STIFF[1]) and "given" in given.reason
    both = choose(ReconstructConfig(lambda_=7.0, clip=90.0), textured, spatially_varying=False)
    assert (both.lambda_, both.clip, both.chroma_spread) == (7.0, 90.0, None)
