"""The `evaluate` command end to end: inputs, report, errors."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from backend.capture.images import write_image, write_mask
from backend.cli import main
from backend.geometry.mesh import save_mesh
from backend.metrics import geometry as geo
from backend.metrics.image import psnr, ssim
from tests.metrics.metric_meshes import blob, similarity

REPO = Path(__file__).resolve().parents[2]


def evaluate(*argv):
    return main(["evaluate", *map(str, argv)])


@pytest.fixture
def meshes(tmp_path):
    truth, pred = blob(), blob().transformed(similarity(0, [0, 0, 1], 1.0, [0.004, 0, 0]))
    save_mesh(tmp_path / "gt.ply", truth)
    save_mesh(tmp_path / "pred.obj", pred)
    return tmp_path / "pred.obj", tmp_path / "gt.ply"


def test_mesh_against_mesh_writes_report(meshes, tmp_path, capsys):
    pred, gt = meshes
    out = tmp_path / "report" / "metrics.json"
    assert evaluate(pred, "--truth", gt, "--samples", 3000, "--seed", 2, "--out", out) == 0
    report = json.loads(out.read_text())
    expected = geo.geometry_metrics(blob().transformed(similarity(0, [0, 0, 1], 1.0, [0.004, 0, 0])),
                                    blob(), 3000, 2)
    for key in ("chamfer_l1", "f1@0.01", "f1@0.005"):
        assert report["geometry"][key] == pytest.approx(expected[key], rel=1e-5)
    assert report["alignment"] == {"method": "none"} and "images" not in report and "albedo" not in report
    table = capsys.readouterr().out
    assert "chamfer_l1" in table and "f1@0.005" in table and f"{report['geometry']['chamfer_l1']:.5f}" in table


def synthetic_capture(root: Path, with_colors: bool) -> blob:
    """A capture folder with ground_truth (mesh and two 16x16 held-out views)."""
    truth = blob()
    if with_colors:
        truth.vertex_colors = (0.5 + 0.2 * truth.vertices).astype(np.float32)
    save_mesh(root / "gt" / "mesh.ply", truth)
    rng = np.random.default_rng(0)
    frames = []
    for name in ("view0", "view1"):
        write_image(root / "gt" / "held_out" / "images" / f"{name}.exr", rng.random((16, 16, 3)).astype(np.float32))
        mask = np.zeros((16, 16), np.float32)
        mask[3:14, 2:12] = 1
        write_mask(root / "gt" / "held_out" / "masks" / f"{name}.png", mask)
        frames.append({"name": name, "image": f"images/{name}.exr", "mask": f"masks/{name}.png",
                       "camera": {"width": 16, "height": 16, "fx": 20.0, "fy": 20.0, "cx": 8.0, "cy": 8.0,
                                  "camera_to_world": np.eye(4).tolist()}})
    held = {"format": "shape-from-tracing-capture", "version": 1, "frames": frames}
    (root / "gt" / "held_out" / "capture.json").write_text(json.dumps(held))
    doc = dict(held, frames=[dict(f, image=f"gt/held_out/{f['image']}", mask=f"gt/held_out/{f['mask']}")
                             for f in frames],
               ground_truth={"mesh": "gt/mesh.ply", "held_out": "gt/held_out/capture.json"})
    (root / "capture.json").write_text(json.dumps(doc))
    return truth


def test_run_folder_against_capture_with_albedo_and_renders(tmp_path, capsys):
    truth = synthetic_capture(tmp_path / "cap", with_colors=True)
    run = tmp_path / "run"
    pred = truth.copy()
    pred.vertex_colors = truth.vertex_colors * np.float32(0.8)
    save_mesh(run / "result.ply", pred)
    from backend.capture.images import read_linear_rgb, read_mask
    held = tmp_path / "cap" / "gt" / "held_out"
    renders = tmp_path / "renders"
    targets = [read_linear_rgb(held / "images" / f"view{i}.exr") for i in range(2)]
    masks = [read_mask(held / "masks" / f"view{i}.png") for i in range(2)]
    write_image(renders / "view0.exr", targets[0])
    write_image(renders / "view1.exr", targets[1] * 1.1)
    out = tmp_path / "r.json"
    code = evaluate(run, "--truth", tmp_path / "cap", "--samples", 2000, "--renders", renders, "--out", out)
    assert code == 0, capsys.readouterr().err
    report = json.loads(out.read_text())
    assert report["geometry"]["chamfer_l1"] == 0 and report["geometry"]["f1@0.005"] == 100
    # predicted albedo is 0.8 x the truth: RMSE = 0.2 x the truth's RMS albedo, up to the
    # gap between a truth sample and its nearest predicted sample; a fitted scale removes it
    gt_albedo = geo.interpolate(truth, truth.vertex_colors, geo.sample_surface(truth, 2000))
    assert report["albedo"]["rmse"] == pytest.approx(0.2 * math.sqrt(np.mean(gt_albedo ** 2)), rel=0.03)
    assert report["albedo"]["rmse_scaled"] < 0.1 * report["albedo"]["rmse"]
    views = report["images"]["views"]
    assert views[0]["psnr"] == "inf" and report["images"]["psnr"] == "inf"  # JSON has no infinity
    assert views[1]["psnr"] == pytest.approx(psnr(targets[1] * 1.1, targets[1], masks[1]), rel=1e-6)
    assert views[1]["ssim"] == pytest.approx(ssim(targets[1] * 1.1, targets[1], masks[1]), rel=1e-6)
    assert "psnr" in capsys.readouterr().out


def test_icp_alignment_for_a_reconstruction_in_another_frame(tmp_path):
    save_mesh(tmp_path / "gt.ply", blob())
    save_mesh(tmp_path / "pred.ply", blob().transformed(similarity(25, [0, 1, 1], 0.6, [2, 0, -1])))
    out = tmp_path / "r.json"
    assert evaluate(tmp_path / "pred.ply", "--truth", tmp_path / "gt.ply", "--align", "icp",
                    "--samples", 3000, "--out", out) == 0
    report = json.loads(out.read_text())
    assert report["alignment"]["scale"] == pytest.approx(1 / 0.6, rel=1e-3)
    assert report["geometry"]["chamfer_l1"] < 1e-3


def bad_inputs(tmp_path):
    save_mesh(tmp_path / "gt.ply", blob())
    (tmp_path / "corrupt.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\n")
    (tmp_path / "run").mkdir()
    (tmp_path / "cap").mkdir()
    (tmp_path / "cap" / "capture.json").write_text(json.dumps(
        {"format": "shape-from-tracing-capture", "version": 1, "frames": [
            {"image": "a.png", "camera": {"width": 4, "height": 4, "fx": 1, "fy": 1, "cx": 2, "cy": 2,
                                          "camera_to_world": np.eye(4).tolist()}}]}))
    gt = tmp_path / "gt.ply"
    return {
        "missing prediction": ([tmp_path / "nope.ply", "--truth", gt], "nope.ply"),
        "run without result": ([tmp_path / "run", "--truth", gt], "result.ply"),
        "corrupt mesh": ([tmp_path / "corrupt.ply", "--truth", gt], "corrupt.ply"),
        "missing truth": ([gt, "--truth", tmp_path / "gone"], "gone"),
        "capture without ground truth": ([gt, "--truth", tmp_path / "cap"], "ground_truth.mesh"),
        "renders without capture": ([gt, "--truth", gt, "--renders", tmp_path], "--renders"),
        "bad sample count": ([gt, "--truth", gt, "--samples", 0], "--samples"),
    }


def test_bad_inputs_exit_2_with_one_line(tmp_path, capsys):
    for case, (argv, named) in bad_inputs(tmp_path).items():
        out = tmp_path / f"{case}.json"
        assert evaluate(*argv, "--out", out) == 2, case
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and named in err and "Fix:" in err, (case, err)
        assert not out.exists()


def test_cli_process_help_and_error():
    env_python = sys.executable
    help_run = subprocess.run([env_python, "-m", "backend", "evaluate", "--help"], cwd=REPO,
                              capture_output=True, text=True)
    assert help_run.returncode == 0 and "--truth" in help_run.stdout
    bad = subprocess.run([env_python, "-m", "backend", "evaluate", "missing.ply", "--truth", "gt.ply"],
                         cwd=REPO, capture_output=True, text=True)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1 and "missing.ply" in bad.stderr


def test_synthetic_capture_truth_scores_itself_perfectly(tiny_capture, tmp_path, capsys):
    # the synth command's ground truth evaluated against itself: geometry, albedo and the
    # held-out and relit photographs used as renders
    import shutil

    from backend.capture import load_capture

    truth = load_capture(tiny_capture, validate=False)
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(truth.path(truth.ground_truth["mesh"]), run / "result.ply")
    for views in ("held_out", "relit"):
        renders = tmp_path / views
        renders.mkdir()
        frames = load_capture(truth.path(truth.ground_truth[views])).frames
        for frame in frames:
            shutil.copy(frame.image, renders / f"{frame.name}{frame.image.suffix}")
        out = tmp_path / f"{views}.json"
        assert evaluate(run, "--truth", tiny_capture, "--samples", 2000, "--renders", renders,
                        "--views", views, "--out", out) == 0, capsys.readouterr().err
        report = json.loads(out.read_text())
        assert report["geometry"]["chamfer_l1"] == 0 and report["geometry"]["f1@0.01"] == 100
        assert report["albedo"]["rmse"] == 0
        assert report["images"]["set"] == views and len(report["images"]["views"]) == len(frames)
        assert report["images"]["psnr"] == "inf" and report["images"]["ssim"] == pytest.approx(1.0)


def test_run_with_specular_lobe_scores_diffuse_and_specular_passes(tiny_capture, tmp_path, capsys):
    # a run whose display mesh is the truth with 0.8x the albedo: its specular-only pass matches
    # the truth's (same seeds), its diffuse-only pass does not
    from backend.capture import load_capture
    from backend.geometry.mesh import load_mesh

    truth = load_capture(tiny_capture, validate=False)
    gt = load_mesh(truth.path(truth.ground_truth["mesh"]))
    assert float(gt.attributes["specular"].max()) > 0
    runs = {}
    for name, specular in (("glossy", gt.attributes["specular"]), ("matte", np.zeros_like(gt.attributes["specular"]))):
        run = tmp_path / name
        display = gt.copy()
        display.vertex_colors = gt.vertex_colors * np.float32(0.8)
        display.attributes["specular"] = specular
        save_mesh(run / "result.ply", display)
        save_mesh(run / "snapshots" / "display.ply", display)
        (run / "snapshot.json").write_text(json.dumps({"mesh": "snapshots/display.ply"}))
        out = tmp_path / f"{name}.json"
        assert evaluate(run, "--truth", tiny_capture, "--samples", 1000, "--out", out) == 0, capsys.readouterr().err
        runs[name] = (json.loads(out.read_text()), capsys.readouterr().out)
    report, table = runs["glossy"]
    parts = report["views"]["held_out"]["components"]
    # the same field, seeds and scene: equal up to the renderer's float summation order
    assert parts["specular"]["psnr"] == "inf" or parts["specular"]["psnr"] > 80
    assert 10 < parts["diffuse"]["psnr"] < 60 and parts["diffuse"]["ssim"] < 1
    assert "psnr diffuse" in table and "psnr specular" in table
    report, table = runs["matte"]
    assert "components" not in report["views"]["held_out"] and "psnr diffuse" not in table


def test_a_run_is_also_scored_with_its_material_on_the_true_geometry(tiny_capture, tmp_path, capsys):
    # the truth's material on a shrunken surface: its held-out views miss the silhouettes, the
    # same material carried back onto the true surface does not
    from backend.capture import load_capture
    from backend.geometry.mesh import load_mesh

    truth = load_capture(tiny_capture, validate=False)
    gt = load_mesh(truth.path(truth.ground_truth["mesh"]))
    shrunk = gt.copy()
    centre = gt.vertices.mean(0)
    shrunk.vertices = (centre + 0.9 * (gt.vertices - centre)).astype(gt.vertices.dtype)
    run = tmp_path / "run"
    save_mesh(run / "result.ply", shrunk)
    save_mesh(run / "snapshots" / "display.ply", shrunk)
    (run / "snapshot.json").write_text(json.dumps({"mesh": "snapshots/display.ply"}))
    out = tmp_path / "report.json"
    assert evaluate(run, "--truth", tiny_capture, "--samples", 1000, "--out", out) == 0, capsys.readouterr().err
    report, table = json.loads(out.read_text()), capsys.readouterr().out
    held, bound = report["views"]["held_out"], report["views"]["true_geometry"]
    assert bound["set"] == "true geometry" and len(bound["views"]) == len(held["views"])
    assert bound["psnr"] == "inf" or bound["psnr"] > held["psnr"] + 3
    assert "psnr true geometry" in table
    assert sorted(p.name for p in (run / "renders" / "true_geometry").iterdir())
