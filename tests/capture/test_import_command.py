"""``python -m backend import``: conversions that work, and bad input that must fail cleanly
(exit code 2, one line naming the file, no output folder left behind)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from backend.capture import Capture, Environment, Frame, load_capture, save_capture
from backend.capture.images import image_size, read_mask, write_image, write_mask
from tests.capture import synthetic as syn
from tests.helpers import run_cli, shared_data


def make_capture(folder: Path, frames: int = 3) -> Path:
    """A small valid capture in our format: frames, masks and a 2:1 environment map."""
    cams = syn.sphere_cameras(frames, fx=60.0, fy=60.0, cx=32.0, cy=24.0)
    items = []
    for i, cam in enumerate(cams):
        silhouette = syn.rasterise(*syn.blob(), cam).astype(np.float32)
        image, mask = folder / "images" / f"{i:04d}.png", folder / "masks" / f"{i:04d}.png"
        write_image(image, np.dstack([silhouette * 0.5] * 3))
        write_mask(mask, silhouette)
        items.append(Frame(f"{i:04d}", image, cam, mask))
    write_image(folder / "env.exr", np.ones((16, 32, 3), np.float32))
    save_capture(Capture(folder, items, Environment(folder / "env.exr", 1.5, 30.0)))
    return folder


def edit_json(path: Path, change) -> None:
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def nerf_source(folder: Path) -> Path:
    cams = syn.sphere_cameras(3)
    return syn.write_transforms(folder, cams, [syn.rasterise(*syn.blob(), c) for c in cams], mask_folder=True)


def test_help():
    proc = run_cli("import", "--help", check=True)
    assert "--max-size" in proc.stdout and "--frames" in proc.stdout


def test_native_capture_downscaled(tmp_path):
    src = make_capture(tmp_path / "src")
    proc = run_cli("import", src, "--out", tmp_path / "out", "--max-size", 32, check=True)
    assert json.loads(proc.stdout.splitlines()[-1])["event"] == "done"
    capture = load_capture(tmp_path / "out")
    assert len(capture.frames) == 3 and capture.environment.strength == 1.5
    for frame in capture.frames:
        assert (frame.camera.width, frame.camera.height) == image_size(frame.image) == (32, 24)
        assert frame.camera.fx == frame.camera.fy == 30.0 and frame.camera.cx == 16.0
        assert frame.mask.is_file() and read_mask(frame.mask).max() == 1.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "src"]  # no temporary folders left


def test_camera_response_and_estimated_environment_survive_import(tmp_path):
    src = make_capture(tmp_path / "src")
    response = {"curve": "srgb", "exposure": 0.8, "white_balance": [1.1, 1.0, 0.9], "provenance": "estimated"}
    edit_json(src / "capture.json", lambda d: (d.__setitem__("camera_response", response),
                                               d["environment"].__setitem__("provenance", "estimated")))
    run_cli("import", src, "--out", tmp_path / "out", check=True)
    doc = json.loads((tmp_path / "out" / "capture.json").read_text())
    assert doc["camera_response"] == response
    assert doc["environment"]["provenance"] == "estimated" and doc["environment"]["rotation_z_deg"] == 30.0
    capture = load_capture(tmp_path / "out")
    assert capture.camera_response.exposure == 0.8 and capture.camera_response.white_balance == (1.1, 1.0, 0.9)
    plain = json.loads((make_capture(tmp_path / "plain") / "capture.json").read_text())
    assert "camera_response" not in plain and "provenance" not in plain["environment"]  # identity: not written


def test_nerf_rgba_masks_written_separately(tmp_path):
    cams = syn.sphere_cameras(3)
    masks = [syn.rasterise(*syn.blob(), c) for c in cams]
    syn.write_transforms(tmp_path / "src", cams, masks, rgba=True)
    run_cli("import", tmp_path / "src", "--out", tmp_path / "out", "--frames", 2, check=True)
    capture = load_capture(tmp_path / "out")
    assert [f.name for f in capture.frames] == ["000", "002"]
    for frame, mask in zip(capture.frames, masks[::2]):
        assert frame.mask.parent.name == "masks" and np.array_equal(read_mask(frame.mask) > 0.5, mask)
        assert frame.camera.fx == frame.camera.fy  # 70 vs 72 px made square by resampling


def test_fox_undistorted(tmp_path):
    src = shared_data("captures", "fox_instant_ngp")
    run_cli("import", src, "--out", tmp_path / "fox", "--frames", 3, "--max-size", 96, check=True)
    capture = load_capture(tmp_path / "fox")
    assert len(capture.frames) == 3
    for frame in capture.frames:
        cam = frame.camera
        assert not cam.distortion and cam.fx == cam.fy
        assert (cam.width, cam.height) == image_size(frame.image) == (54, 96)
    assert capture.provenance["import"]["resampled_frames"] == 3


def test_dino_masks_into_output_only(tmp_path):
    src = shared_data("captures", "middlebury_dinoSparseRing")
    before = sorted(p.name for p in src.iterdir())
    run_cli("import", src, "--out", tmp_path / "dino", "--frames", 4, "--max-size", 160, check=True)
    assert sorted(p.name for p in src.iterdir()) == before
    capture = load_capture(tmp_path / "dino")
    assert all(f.mask.is_file() and 0.05 < read_mask(f.mask).mean() < 0.7 for f in capture.frames)
    assert not (tmp_path / "dino" / ".import").exists()


def _missing_image(src):
    (src / "images" / "0001.png").unlink()
    return src, "images/0001.png"


def _mask_size(src):
    write_mask(src / "masks" / "0001.png", np.ones((10, 10)))
    return src, "masks/0001.png"


def _mask_count(src):
    edit_json(src / "capture.json", lambda d: d["frames"][1].pop("mask"))
    return src, "images/0001.png: frame 0001 has no mask"


def _missing_mask_file(src):
    path = nerf_source(src)
    (src / "masks" / "001.png").unlink()
    return path, "masks/001.png"


def _nan_pose(src):
    path = nerf_source(src)
    edit_json(path, lambda d: d["frames"][1]["transform_matrix"][0].__setitem__(3, float("nan")))
    return path, "transforms.json"


def _nan_pose_native(src):
    edit_json(src / "capture.json", lambda d: d["frames"][2]["camera"]["camera_to_world"][1].__setitem__(1, float("nan")))
    return src, "capture.json"


def _singular_pose(src):
    path = nerf_source(src)
    edit_json(path, lambda d: d["frames"][0].__setitem__("transform_matrix", [[0, 0, 0, 1]] * 3 + [[0, 0, 0, 1]]))
    return path, "transforms.json"


def _unreadable_env(src):
    (src / "env.exr").write_bytes(b"this is not an EXR file")
    return src, "env.exr"


def _not_equirectangular(src):
    write_image(src / "env.exr", np.ones((20, 30, 3), np.float32))  # 3:2
    return src, "env.exr"


def _empty_masks(src):
    for i in range(3):
        write_mask(src / "masks" / f"{i:04d}.png", np.zeros((48, 64)))
    return src, "masks"


def _bad_response(src):
    edit_json(src / "capture.json", lambda d: d.__setitem__("camera_response", {"exposure": 1.0,
                                                                                "white_balance": [1.0, 0.0, 1.0]}))
    return src, "capture.json"


def _unknown_curve(src):
    edit_json(src / "capture.json", lambda d: d.__setitem__("camera_response", {"curve": "log-c"}))
    return src, "capture.json"


def _unknown_layout(src):
    empty = src.parent / "empty"
    empty.mkdir()
    return empty, "empty"


@pytest.mark.parametrize("breaks", [_missing_image, _mask_size, _mask_count, _missing_mask_file, _nan_pose,
                                    _nan_pose_native, _singular_pose, _unreadable_env, _not_equirectangular,
                                    _empty_masks, _bad_response, _unknown_curve, _unknown_layout], ids=lambda f: f.__name__.strip("_"))
def test_bad_input(tmp_path, breaks):
    src = make_capture(tmp_path / "src")
    if breaks in (_missing_mask_file, _nan_pose, _singular_pose):
        src = tmp_path / "nerf"
    given, named = breaks(src)
    out = tmp_path / "out" / "capture"
    proc = run_cli("import", given, "--out", out)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and named in lines[0], proc.stderr
    assert "Fix:" in lines[0]
    assert not out.exists() and not any((tmp_path / "out").iterdir())


def test_output_folder_not_replaced(tmp_path):
    src = make_capture(tmp_path / "src")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "keep.txt").write_text("mine")
    proc = run_cli("import", src, "--out", tmp_path / "out")
    assert proc.returncode == 2 and "--overwrite" in proc.stderr
    assert (tmp_path / "out" / "keep.txt").read_text() == "mine"
    run_cli("import", src, "--out", tmp_path / "out", "--overwrite", check=True)
    assert (tmp_path / "out" / "capture.json").is_file() and not (tmp_path / "out" / "keep.txt").exists()
