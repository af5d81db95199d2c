"""``reconstruct --materials N|auto``: how many materials the frames' colours show, and the
option's bad values."""

from __future__ import annotations

import numpy as np
import pytest

from backend.material.labels import choose_material_count
from tests.helpers import run_cli


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
