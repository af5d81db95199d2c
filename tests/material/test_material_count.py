"""``reconstruct --materials N|auto``: how many materials the frames' colours show, and the
option's bad values."""

from __future__ import annotations

import numpy as np
import pytest

from backend.material.labels import choose_material_count
from tests.helpers import run_cli

# the colour-bleeding corner's paints (backend.synth.corner)
GREY, RED, BLUE = (0.7, 0.7, 0.7), (0.75, 0.08, 0.06), (0.08, 0.12, 0.75)


def _frames(paints: list[tuple[float, float, float]], seed: int = 0):
    """Four 64 px frames of a disc split into vertical bands of ``paints``, with a fine texture."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:64, 0:64]
    mask = ((x - 32) ** 2 + (y - 32) ** 2 < 28 ** 2).astype(np.float32)
    band = np.minimum(x * len(paints) // 64, len(paints) - 1)
    images = []
    for _ in range(4):
        texture = 1 + 0.15 * rng.standard_normal((64, 64, 1))
        images.append(np.asarray(paints, np.float64)[band] * texture * mask[..., None])
    return images, [mask] * 4


def _under_a_lamp(paints: list[tuple[float, float, float]], seed: int = 0):
    """Four 64 px frames of a disc in bands of ``paints`` lit by a lamp 0.2 above the plane just
    off one edge (a different edge in each frame): the inverse-square falloff and the cosine
    spread each paint's brightness over more than an order of magnitude across the disc, as the
    lamp inside the colour-bleeding corner does; with a fine texture and additive noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:64, 0:64] / 64.0
    mask = ((x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.44 ** 2).astype(np.float32)
    band = np.minimum((x * len(paints)).astype(int), len(paints) - 1)
    images = []
    for lamp in ([-0.1, 0.5], [0.5, -0.1], [1.1, 0.5], [0.5, 1.1]):
        height = 0.2
        light = 0.08 * height / ((x - lamp[0]) ** 2 + (y - lamp[1]) ** 2 + height ** 2) ** 1.5  # cos / r^2
        texture = 1 + 0.1 * rng.standard_normal((64, 64, 1))
        rgb = np.asarray(paints, np.float64)[band] * texture * light[..., None]
        rgb = np.clip(rgb + 0.002 * rng.standard_normal(rgb.shape), 0, None)
        images.append(rgb * mask[..., None])
    return images, [mask] * 4


def test_a_lamps_falloff_is_no_paint():
    """Shading scales each pixel's brightness; the count reads chromaticity only."""
    images, masks = _under_a_lamp([(0.7, 0.7, 0.7)])
    obj = masks[0] > 0.5
    spread = [np.percentile(im.sum(-1)[obj], 95) / np.percentile(im.sum(-1)[obj], 5) for im in images]
    assert min(spread) > 10, spread  # the falloff is strong
    assert choose_material_count(images, masks) == 1


@pytest.mark.parametrize("paints", [[RED, BLUE], [GREY, RED, BLUE]], ids=["two", "three"])
def test_paints_under_a_lamps_falloff_keep_their_count(paints):
    images, masks = _under_a_lamp(paints)
    assert choose_material_count(images, masks) == len(paints)


def test_one_textured_paint_is_one_material():
    images, masks = _frames([(0.6, 0.3, 0.2)])
    assert choose_material_count(images, masks) == 1


def test_two_paints_are_two_materials():
    images, masks = _frames([(0.7, 0.1, 0.1), (0.1, 0.2, 0.7)])
    assert choose_material_count(images, masks) == 2


@pytest.mark.parametrize("value", ["0", "many"])
def test_bad_material_counts_fail_with_one_line(tiny_capture, tmp_path, value):
    proc = run_cli("reconstruct", tiny_capture, "--out", tmp_path / "run", "--materials", value)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.strip().count("\n") == 0 and "--materials" in proc.stderr
    assert not (tmp_path / "run" / "result.ply").exists()
