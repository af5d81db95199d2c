"""Linear images (EXR, Radiance HDR) read through Mitsuba's Bitmap: values, orientation, channels."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest

from backend.capture.images import area_resize, image_size, read_linear_rgb, read_rgba, write_image
from backend.errors import InputError


def test_exr_round_trip_keeps_values_rows_and_alpha(tmp_path):
    rng = np.random.default_rng(0)
    rgb = (rng.random((5, 7, 3)) * 40).astype(np.float32)
    rgb[0] = 100.0  # the top row
    write_image(tmp_path / "a.exr", rgb)
    arr, linear = read_rgba(tmp_path / "a.exr")
    assert linear and arr.dtype == np.float32 and np.array_equal(arr, rgb)
    rgba = rng.random((4, 3, 4)).astype(np.float32)
    write_image(tmp_path / "b.exr", rgba)
    assert np.array_equal(read_rgba(tmp_path / "b.exr")[0], rgba)
    assert image_size(tmp_path / "a.exr") == (7, 5)


def test_grey_exr_becomes_rgb(tmp_path):
    y = np.arange(12, dtype=np.float32).reshape(3, 4)
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"Y": y}) as f:
        f.write(str(tmp_path / "y.exr"))
    rgb = read_linear_rgb(tmp_path / "y.exr")
    assert rgb.shape == (3, 4, 3) and np.array_equal(rgb, np.repeat(y[..., None], 3, -1))


def test_radiance_hdr_values_and_orientation(tmp_path):
    """A flat (not run-length encoded) RGBE file: 2 rows x 3 columns, top row first on disk."""
    pixels = np.array([[[128, 64, 32, 129], [128, 128, 128, 128], [0, 0, 0, 0]],
                       [[255, 0, 0, 130], [64, 64, 64, 128], [128, 0, 0, 127]]], np.uint8)
    (tmp_path / "sky.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 3\n" + pixels.tobytes())
    rgb = read_linear_rgb(tmp_path / "sky.hdr")
    e = pixels[..., 3].astype(np.int32)
    want = np.where(e[..., None] > 0, pixels[..., :3] * np.ldexp(1.0, e - 136)[..., None], 0.0)
    assert rgb.shape == (2, 3, 3) and np.allclose(rgb, want, rtol=1e-6)


@pytest.mark.parametrize("name", ["bad.exr", "bad.hdr"])
def test_unreadable_linear_image_is_an_input_error(tmp_path, name):
    (tmp_path / name).write_bytes(b"not an image")
    with pytest.raises(InputError, match="cannot read"):
        read_rgba(tmp_path / name)


@pytest.mark.parametrize("size, out", [((48, 36), (32, 24)), ((40, 30), (16, 12)), ((30, 20), (45, 30))])
def test_area_resize_is_the_mean_over_each_output_pixel_s_rectangle(size, out):
    """Against an exact reference: every input pixel repeated k times (k making each output
    pixel a whole block), then block means. At 1.5x and 2.5x a filter weighing whole pixels by
    their centres is a quarter of an input pixel off; this is exact (and up-sampling too)."""
    rng = np.random.default_rng(5)
    (w, h), (ow, oh) = size, out
    img = rng.random((h, w, 3)).astype(np.float32)
    k = int(np.lcm(w, ow) // w)
    fine = img.repeat(k, 0).repeat(k, 1)
    by = fine.shape[0] // oh, fine.shape[1] // ow
    reference = fine.reshape(oh, by[0], ow, by[1], 3).mean((1, 3))
    got = area_resize(img, ow, oh)
    assert got.shape == (oh, ow, 3) and got.dtype == np.float32
    np.testing.assert_allclose(got, reference, atol=1e-5)
    np.testing.assert_allclose(area_resize(img[..., 0], ow, oh), reference[..., 0], atol=1e-5)
