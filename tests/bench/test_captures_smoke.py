"""``bench captures`` end to end at toy size on the real DTU scan 65: the real import, a real
reconstruct with the lighting estimated and every 6th frame held out, and the contact sheet
rendered from the finished run."""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from backend.bench import captures, names
from tests.helpers import shared_data


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    shared_data("captures", "dtu_scan65")
    out = tmp_path_factory.mktemp("captures")
    parser = argparse.ArgumentParser()
    captures.add_arguments(parser)
    args = parser.parse_args(["--out", str(out), "--captures", "dtu", "--minutes", "0.5", "--import-size", "96",
                              "--max-size", "32", "--spp", "8", "--fitted", "1",
                              "--reconstruct-args", "--iterations 6 --coarse-size 32 --initial-faces 500"])
    return args, captures.run(args)


def test_registered_under_its_name():
    assert "captures" in names()


def test_runs_and_scores_held_out_frames(bench):
    args, rc = bench
    assert rc == 0
    (result,) = json.loads((args.out / "captures.json").read_text())
    assert result["capture"] == "dtu" and result["frames"] == 13
    # every 6th of 13 frames: two held out, never fitted, each scored
    assert len(result["held_out_frames"]) == 2 and set(result["held_out_psnr_each"]) == set(result["held_out_frames"])
    assert all(math.isfinite(p) and 0 < p < 60 for p in result["held_out_psnr_each"].values())
    assert result["lighting"] == "rig" and result["environment_map"]  # DTU's lamps travel with the camera
    lighting = json.loads((args.out / "dtu" / "run" / "report.json").read_text())["lighting"]
    assert lighting["frame"] == "camera"
    report = json.loads((args.out / "dtu" / "run" / "report.json").read_text())
    assert set(report["accuracy_time"]["held_out_views"]) == set(result["held_out_frames"])
    assert report["accuracy_time"]["fitted_views"] == 11


def test_contact_sheet_has_a_row_per_scored_frame(bench):
    args, _ = bench
    sheet = np.asarray(Image.open(args.out / "dtu" / "contact_sheet.png"))
    (result,) = json.loads((args.out / "captures.json").read_text())
    rows = len(result["held_out_frames"]) + 1  # and one fitted frame
    h = 24  # DTU is 4:3: 32 x 24 at --max-size 32
    assert sheet.shape[0] == 14 + rows * (h + 14 + 4) + 4 and sheet.shape[1] == 3 * 32 + 4 * 4
    assert sheet[..., :3].std() > 5  # photos and renders, not an empty canvas


def test_a_lighting_of_the_users_wins_over_the_captures():
    dtu = captures.CAPTURES["dtu"]
    assert captures.lighting_args(dtu, "--iterations 6") == ["--lighting", "rig", "--iterations", "6"]
    assert captures.lighting_args(dtu, "--lighting flash") == ["--lighting", "flash"]
    assert captures.lighting_args(captures.CAPTURES["dino"], "")[:2] == ["--lighting", "estimate"]


def test_unknown_capture_is_a_clear_error(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    captures.add_arguments(parser)
    assert captures.run(parser.parse_args(["--out", str(tmp_path), "--captures", "moon"])) == 2
    assert "unknown capture 'moon'" in capsys.readouterr().err


def test_pieces_switch_one_real_camera_piece_each():
    base = captures.PIECES["base"]
    assert {"--exposure", "--refine-cameras", "--texture-stage"} <= set(base) and "--lighting" not in base
    for piece, flag, value in (("exposure", "--exposure", "per-frame"), ("cameras", "--refine-cameras", "on"),
                               ("texture", "--texture-stage", "on"), ("lighting", "--lighting", "auto")):
        args = list(captures.PIECES[piece])
        assert args[args.index(flag) + 1] == value
        changed = {a for a in zip(args[::2], args[1::2])} - {a for a in zip(base[::2], base[1::2])}
        assert changed == {(flag, value)}, piece  # that piece alone on top of base
    every = dict(zip(captures.PIECES["all"][::2], captures.PIECES["all"][1::2]))
    assert every == {"--exposure": "per-frame", "--refine-cameras": "on", "--texture-stage": "on", "--lighting": "auto"}


def test_a_pieces_run_writes_a_row_per_piece(bench, tmp_path):
    """Two models on the capture the module's bench imported (reused, not imported again)."""
    args, _ = bench
    parser = argparse.ArgumentParser()
    captures.add_arguments(parser)
    piece_args = parser.parse_args(["--out", str(args.out), "--captures", "dtu", "--minutes", "0.3",
                                    "--import-size", "96", "--max-size", "32", "--spp", "4", "--fitted", "1",
                                    "--pieces", "base,cameras",
                                    "--reconstruct-args", "--iterations 4 --coarse-size 32 --initial-faces 500"])
    assert captures.run(piece_args) == 0
    results = json.loads((args.out / "captures.json").read_text())
    assert [r["piece"] for r in results] == ["base", "cameras"]
    for r in results:
        assert math.isfinite(r["held_out_psnr"]) and 0 < r["held_out_ssim"] <= 1
        assert (args.out / "dtu" / r["piece"] / "contact_sheet.png").is_file()
        report = json.loads((args.out / "dtu" / r["piece"] / "run" / "report.json").read_text())
        assert report["settings"]["exposure"] == "off"
    record = json.loads((Path(os.environ["SFT_RECORDS"]) / "captures-pieces.json").read_text())
    assert [row["run"] for row in record["figures"]["rows"]] == ["dtu/base", "dtu/cameras"]


def test_an_unknown_piece_is_a_clear_error(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    captures.add_arguments(parser)
    assert captures.run(parser.parse_args(["--out", str(tmp_path), "--captures", "dtu", "--pieces", "magic"])) == 2
    assert "unknown piece 'magic'" in capsys.readouterr().err
