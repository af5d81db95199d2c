"""``bench realworld`` end to end at toy size: a real Cycles orbit video (bpy in a child
process), real capture-from-video (SfM, scene frame, lighting alignment), a few reconstruct
steps, and the scoring against the render's truth."""

from __future__ import annotations

import argparse
import json
import math

import pytest

from backend.bench import names, realworld
from tests.helpers import shared_data


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    shared_data("meshes", "crane", "spot", "spot.obj")
    out = tmp_path_factory.mktemp("realworld")
    parser = argparse.ArgumentParser()
    realworld.add_arguments(parser)
    args = parser.parse_args(["--out", str(out), "--frames", "12", "--size", "192x108", "--samples", "1",
                              "--minutes", "5", "--margin", "0",
                              "--reconstruct-args", "--iterations 2 --max-size 32 --coarse-size 32 "
                                                    "--initial-faces 500 --effects specular"])
    return args, realworld.run(args)


def test_registered_under_its_name():
    assert "realworld" in names()


def test_harness_runs_and_prints_its_figures(bench, capsys):
    args, rc = bench
    assert rc == 0
    figures = json.loads((args.out / "bench_realworld.json").read_text())
    truth = json.loads((args.out / "orbit" / "truth.json").read_text())
    assert len(truth["camera_to_world"]) == 12 and truth["environment"]["rotation_z_deg"] == 40.0
    assert figures["video_frames"] == 12 and 3 <= figures["registered"] <= 12
    # Background features (the map, at infinity) must not leave wild points behind.
    assert 0 < figures["sfm"]["reprojection_error_px"] < 2
    # SfM's world is only a similarity away from Blender's: the cameras line up after one.
    assert figures["camera_centre_error_pct"]["max"] < 10 and figures["camera_rotation_error_deg"]["max"] < 5
    for key in ("geometry", "geometry_cameras"):
        assert 0 < figures[key]["f1@0.01"] <= 100 and 0 < figures[key]["chamfer_l1"] < 0.2
    env = figures["env"]
    assert math.isfinite(env["error_deg"]) and 0 <= env["error_deg"] <= 180
    assert figures["minutes"]["total"] > 0 and set(figures["goals"]) == {"f1>=80", "env_rotation<=5deg", "under_5_min"}


def test_the_video_is_8_bit_srgb_with_index_paired_masks(bench):
    import av
    import numpy as np
    from PIL import Image

    args, _ = bench
    orbit = args.out / "orbit"
    with av.open(str(orbit / "orbit.mp4")) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    masks = sorted((orbit / "masks").glob("*.png"))
    assert len(frames) == len(masks) == 12 and frames[0].shape == (108, 192, 3)
    mask = np.asarray(Image.open(masks[0]))
    assert mask.dtype == np.uint8 and mask.shape == (108, 192) and 0.02 < (mask > 127).mean() < 0.6
    inside, outside = frames[0][mask > 250], frames[0][mask < 5]
    assert inside.std() > 10 and outside.std() > 5  # textured object, and the map behind it
