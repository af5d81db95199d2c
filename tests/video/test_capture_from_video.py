"""``capture-from-video``: bad input fails fast and cleanly; the Middlebury dino goes through
SfM and the scene frame with poses close to its calibration."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.capture.images import write_image, write_mask
from tests.helpers import run_cli, shared_data
from tests.video.media import moving_frames, write_video

DINO = ("captures", "middlebury_dinoSparseRing")
# The dataset README's tight bounding box of the dino, in its calibration's world.
DINO_BOX = np.array([[-0.061897, -0.018874, -0.057845], [0.010897, 0.068227, 0.015495]])


@pytest.fixture(scope="module")
def env(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("env") / "sky.exr"
    write_image(path, np.full((8, 16, 3), 0.5, np.float32))
    return path


def _disc_masks(folder: Path, count: int, width: int, height: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    y, x = np.mgrid[0:height, 0:width]
    disc = ((x - width / 2) ** 2 + (y - height / 2) ** 2 < (height / 4) ** 2).astype(np.float32)
    for i in range(count):
        write_mask(folder / f"{i:04d}.png", disc)
    return folder


def _events(stdout: str) -> list[dict]:
    return [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]


def test_mask_count_mismatch_is_rejected_before_any_work(tmp_path, env):
    video = write_video(tmp_path / "orbit.mp4", moving_frames(12, 96, 64))
    masks = _disc_masks(tmp_path / "masks", 11, 96, 64)
    out = tmp_path / "capture"
    proc = run_cli("capture-from-video", video, "--masks", masks, "--env", env, "--out", out)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "Traceback" not in proc.stderr
    assert "11 masks for 12 frames" in proc.stderr and str(masks) in proc.stderr
    assert _events(proc.stdout) == []  # not even frame picking started
    assert not out.exists()


@pytest.mark.parametrize("masks_count, size, expected", [(11, (96, 64), "11 masks for 12 frames"),
                                                       (12, (64, 48), "masks are 64x48 but the frames are 96x64")])
def test_reconstruct_from_video_rejects_mismatched_masks(tmp_path, env, masks_count, size, expected):
    video = write_video(tmp_path / "orbit.mp4", moving_frames(12, 96, 64))
    masks = _disc_masks(tmp_path / "masks", masks_count, *size)
    run = tmp_path / "run"
    proc = run_cli("reconstruct", video, "--masks", masks, "--env", env, "--out", run)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.strip().count("\n") == 0 and "Traceback" not in proc.stderr
    assert expected in proc.stderr and str(masks) in proc.stderr and "Fix:" in proc.stderr
    assert proc.stdout == "" and not run.exists()


def test_reconstruct_video_needs_masks_and_a_light(tmp_path, env):
    video = write_video(tmp_path / "orbit.mp4", moving_frames(4, 96, 64))
    proc = run_cli("reconstruct", video, "--env", env, "--out", tmp_path / "run")
    assert proc.returncode == 2 and "a video needs its object masks" in proc.stderr, proc.stderr
    masks = _disc_masks(tmp_path / "masks", 4, 96, 64)
    # with no --env the lighting is estimated by default; --lighting none keeps the error
    proc = run_cli("reconstruct", video, "--masks", masks, "--lighting", "none", "--out", tmp_path / "run")
    assert proc.returncode == 2 and "no light source" in proc.stderr and "--env HDR" in proc.stderr, proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "Traceback" not in proc.stderr
    assert not (tmp_path / "run").exists()


def test_textureless_video_fails_with_the_registered_count(tmp_path, env):
    flat = [np.full((120, 160, 3), 128, np.uint8) for _ in range(8)]
    video = write_video(tmp_path / "flat.mp4", flat)
    masks = _disc_masks(tmp_path / "masks", 8, 160, 120)
    out = tmp_path / "capture"
    proc = run_cli("capture-from-video", video, "--masks", masks, "--env", env, "--out", out, "--frames", 4)
    assert proc.returncode == 2, proc.stderr[-2000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith("error: ") and str(video) in line
    assert "registered only 0 of 4 frames" in line and "Fix:" in line
    assert "Traceback" not in proc.stderr
    assert not out.exists() and list(tmp_path.glob(".capture*")) == []


def _dino_calibration(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``name k11..k33 r11..r33 t1 t2 t3`` per line (first line: the count) -> (R, centre)."""
    cameras = {}
    for line in path.read_text().splitlines()[1:]:
        if line.strip():
            v = line.split()
            R = np.array(v[10:19], float).reshape(3, 3)
            cameras[Path(v[0]).stem] = (R, -R.T @ np.array(v[19:22], float))
    return cameras


def _umeyama(src: np.ndarray, dst: np.ndarray):
    """(s, R, t) minimising |dst - (s R src + t)|^2."""
    ms, md = src.mean(0), dst.mean(0)
    u, d, vt = np.linalg.svd((dst - md).T @ (src - ms) / len(src))
    e = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ e @ vt
    s = float(np.trace(np.diag(d) @ e) / ((src - ms) ** 2).sum(1).mean())
    return s, R, md - s * R @ ms


@pytest.fixture(scope="module")
def dino_capture(tmp_path_factory, env):
    from backend.capture.importers.middlebury import derive_mask

    source = shared_data(*DINO)
    root = tmp_path_factory.mktemp("dino")
    for image in sorted(source.glob("dinoSR*.png")):  # the README's silhouette recipe
        write_mask(root / "masks" / image.name, derive_mask(image).astype(np.float32))
    proc = run_cli("capture-from-video", "--images", source, "--masks", root / "masks", "--env", env,
                   "--out", root / "capture", check=True)
    return root / "capture", _events(proc.stdout), _dino_calibration(source / "dinoSR_par.txt")


def test_dino_poses_match_the_calibration(dino_capture):
    folder, events, truth = dino_capture
    sfm = next(e for e in events if e["event"] == "sfm")
    assert (sfm["registered"], sfm["total"]) == (16, 16)
    assert 0 < sfm["reprojection_error_px"] < 1.0
    doc = json.loads((folder / "capture.json").read_text())
    assert len(doc["frames"]) == 16
    ours, theirs, R_ours, R_theirs = [], [], [], []
    for frame in doc["frames"]:
        c2w = np.array(frame["camera"]["camera_to_world"])
        ours.append(c2w[:3, 3])
        R_ours.append((c2w[:3, :3] @ np.diag([1.0, -1.0, -1.0])).T)  # world-to-camera, OpenCV axes
        R, centre = truth[frame["name"]]
        theirs.append(centre)
        R_theirs.append(R)
    ours, theirs = np.array(ours), np.array(theirs)
    s, R, t = _umeyama(ours, theirs)
    radius = np.linalg.norm(theirs - theirs.mean(0), axis=1).mean()
    centre_error = np.linalg.norm(s * ours @ R.T + t - theirs, axis=1) / radius
    rotation_error = np.degrees([Rotation.from_matrix(Rt @ (Ro @ R.T).T).magnitude()
                                 for Ro, Rt in zip(R_ours, R_theirs)])
    print(f"dino: centre error / ring radius max {centre_error.max():.2%} mean {centre_error.mean():.2%}; "
          f"rotation error max {rotation_error.max():.2f} mean {rotation_error.mean():.2f} deg")
    # the goal: < 2 degrees, < 2 % of the ring radius (the silhouettes' tangencies in the
    # adjustment hold its weak links)
    assert rotation_error.max() < 2.0
    assert centre_error.mean() < 0.01
    assert centre_error.max() < 0.02
    silhouettes = sfm["silhouettes"]
    # SfM's threads make its start vary from run to run; from some starts the poorest thresholded
    # mask (the dino's shadowed side) fits the others badly enough to leave the adjustment
    assert silhouettes["applied"] and len(silhouettes["dropped"]) <= 1
    assert silhouettes["frames"] + len(silhouettes["dropped"]) == 16
    assert silhouettes["tangency_median_px"][1] < 0.2 * silhouettes["tangency_median_px"][0]

    # Scene frame: Z up along the gantry's axis (+Y there, the dino's base at -Y), the object
    # near the origin and about 1 across. The thresholded masks lose the dino's shadowed side,
    # so what lies inside every mask is smaller than the README's box: loose bounds.
    assert R[:, 2] @ [0, 1, 0] > 0.99
    box_centre, box_size = DINO_BOX.mean(0), DINO_BOX[1] - DINO_BOX[0]
    print(f"dino: origin {np.linalg.norm(t - box_centre) / box_size.max():.0%} of the box from its centre; "
          f"1 unit = {s / np.linalg.norm(box_size):.2f} box diagonals ({doc['provenance']['scene_frame']['size']})")
    assert np.linalg.norm(t - box_centre) < 0.25 * box_size.max()
    assert 0.5 < s / np.linalg.norm(box_size) < 1.2
    # Lighting: aligned against the hull (a uniform test map leaves the rotation undetermined,
    # so only the bookkeeping is checked here; tests/lighting checks the estimate itself).
    lighting = doc["provenance"]["lighting"]
    assert lighting["aligned"] is True and lighting["rotation_given"] is False
    assert len(lighting["coarse_curve"]) == 180 and lighting["refine_curve"] and lighting["pixels"] >= 50
    assert doc["environment"]["provenance"] == "estimated"
    assert doc["environment"]["strength"] == pytest.approx(lighting["strength"]) and lighting["strength"] > 0
    assert doc["camera_response"] == {"curve": "srgb", "exposure": 1.0, "white_balance": [1.0, 1.0, 1.0],
                                      "provenance": "normalised"}
    assert any(e["event"] == "stage" and e["stage"] == "lighting" for e in events)
    assert next(e for e in events if e["event"] == "done")["lighting"]["aligned"] is True
