"""The lighting a run fitted, for its held-out views (backend.lighting.fitted), as both scorers
use it: ``evaluate`` on a finished flash or estimate run, and ``--track-accuracy`` during a
flash run. Tiny synthetic captures whose capture.json (and held-out views) name no light, real
reconstructions and renders: the held-out views rendered under the capture's own (absent)
lighting are black; under the fitted lighting they match the photographs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.images import write_image  # noqa: E402
from backend.capture.load import load_capture  # noqa: E402
from backend.capture.model import Capture, Environment, Frame, PointLight  # noqa: E402
from backend.cli import main  # noqa: E402
from backend.errors import InputError  # noqa: E402
from backend.geometry.mesh import load_mesh  # noqa: E402
from backend.lighting import convention, fitted  # noqa: E402
from backend.lighting.estimated_map import EstimatedEnvironment  # noqa: E402
from backend.lighting.flash import Flash  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.metrics.evaluate import _view_metrics  # noqa: E402
from backend.render.views import render_views  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402
from tests.helpers import run_cli, shared_data  # noqa: E402

TRUE_INTENSITY = 2.0  # W/sr
TRUE_ALBEDO = (0.4, 0.3, 0.2)  # mean 0.3: the convention's 0.5 is 5/3 of it


def strip_light(capture: Path) -> None:
    """Drop every light from a capture folder's capture.json and its held-out views' (as a
    DTU-like capture, or one lit by a map nobody recorded, would come)."""
    for path in (capture / "capture.json", capture / "gt" / "held_out" / "capture.json"):
        data = json.loads(path.read_text())
        data.pop("environment", None)
        for frame in data["frames"]:
            frame.pop("lights", None)
        path.write_text(json.dumps(data))


def evaluate(run: Path, truth: Path) -> dict:
    out = run.parent / f"{run.name}-metrics.json"
    assert main(["evaluate", str(run), "--truth", str(truth), "--samples", "2000", "--out", str(out)]) == 0
    return json.loads(out.read_text())


def unlit_psnr(run: Path, truth: Path) -> float:
    """What evaluate gave before the fitted lighting: the display mesh at the held-out views
    under the capture's own lighting (none here: black)."""
    capture = load_capture(truth, validate=False)
    views = load_capture(capture.path(capture.ground_truth["held_out"]))
    display = load_mesh(run / json.loads((run / "snapshot.json").read_text())["mesh"])
    out = run.parent / f"{run.name}-unlit"
    for name, image in render_views(display, views).items():
        write_image(out / f"{name}.exr", image)
    return _view_metrics(capture, out, "held_out")["psnr"]


# -- the function itself (no render) ------------------------------------------------------------
def test_light_views_per_model(tmp_path):
    cams = layout.orbit_cameras(layout.fibonacci_sphere(3), np.zeros(3), 0.6, 8)
    own = Environment(tmp_path / "own.exr", 2.0)
    frames = [Frame(str(k), tmp_path / f"{k}.exr", c, lights=[PointLight(np.ones(3), np.full(3, 9.0))])
              for k, c in enumerate(cams)]
    views = Capture(tmp_path, frames, own)
    material = MeshColorMaterial(procedural.blob(2), 1)
    material.light_factor = 1.5
    lit = fitted.light_views(views, fitted.from_live(None, material))  # captured: own lights, map x factor
    assert lit.environment.strength == pytest.approx(3.0) and lit.frames[0].lights == frames[0].lights
    lit = fitted.light_views(views, fitted.from_live(Flash(Capture(tmp_path, []), [math.log(0.7)]), material))
    assert lit.environment is None
    for frame, cam in zip(lit.frames, cams):
        assert len(frame.lights) == 1 and np.allclose(frame.lights[0].position, cam.centre)
        assert np.allclose(frame.lights[0].intensity, 0.7)
    assert all(len(f.lights) == 1 and f.lights[0].intensity[0] == 9.0 for f in frames)  # the views untouched
    estimate = EstimatedEnvironment(np.zeros((8, 16, 3), np.float32), tmp_path / "e.exr")
    lit = fitted.light_views(views, fitted.from_live(estimate, material))
    assert lit.environment.provenance == "estimated" and lit.environment.strength == pytest.approx(1.5)
    assert views.environment is own


def test_from_run_reads_the_report_and_the_map(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    assert fitted.from_run(run) == fitted.RunLighting()  # no report: captured, factor 1
    (run / "report.json").write_text(json.dumps({"lighting": {"model": "flash", "intensity": 1.25},
                                                 "material": {"light_factor": 1.0}}))
    flash = fitted.from_run(run)
    assert flash.model == "flash" and np.allclose(flash.intensity, 1.25) and flash.convention
    assert "1.25 W/sr" in flash.describe()
    (run / "report.json").write_text(json.dumps({"lighting": {"model": "environment map (estimated)",
                                                              "file": "environment.exr"}}))
    with pytest.raises(InputError, match="estimated environment map is missing"):
        fitted.from_run(run)
    (run / "environment.exr").write_bytes(b"")
    assert fitted.from_run(run).environment.path == run / "environment.exr"
    (run / "report.json").write_text(json.dumps({"lighting": {"model": "captured"}, "material": {"light_factor": 2}}))
    assert fitted.from_run(run) == fitted.RunLighting("captured", light_factor=2.0)


# -- flash: evaluate and the tracker on one short real run --------------------------------------
FLASH_SETTINGS = {"max_levels": 1, "polish_rounds": 0, "accuracy_every_s": 1}
FLASH_FAST = ["--iterations", "20", "--max-size", "16", "--coarse-size", "16", "--initial-faces", "800",
              "--spp", "4", "--effects=-specular"]


@pytest.fixture(scope="module")
def flash_run(tmp_path_factory) -> tuple[Path, Path]:
    """(run, capture): a diffuse object under a flash of ``TRUE_INTENSITY`` at each camera, its
    capture.json and held-out views naming no light, reconstructed with ``--lighting flash``
    and ``--track-accuracy`` (the 2 ground-truth held-out views)."""
    root = tmp_path_factory.mktemp("flash")
    run_cli("synth", "--out", root / "capture", "--lighting", "flash", "--light-intensity", TRUE_INTENSITY,
            "--albedo", ",".join(map(str, TRUE_ALBEDO)), "--specular", 0, "--views", 8, "--resolution", 32,
            "--spp", 32, "--held-out", 2, check=True)
    strip_light(root / "capture")
    proc = run_cli("reconstruct", root / "capture", "--out", root / "run", "--lighting", "flash", *FLASH_FAST,
                   "--track-accuracy", timeout=300, env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(FLASH_SETTINGS)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    return root / "run", root / "capture"


def test_evaluate_renders_a_flash_run_under_its_fitted_flash(flash_run):
    run, capture = flash_run
    report = evaluate(run, capture)
    held, before = report["views"]["held_out"], unlit_psnr(run, capture)
    assert "fitted flash" in held["lighting"]
    assert held["psnr"] > 22 and held["psnr"] > before + 10, (held["psnr"], before)
    assert report["views"]["true_geometry"]["psnr"] > 22
    # relit under a map the run never saw: the convention's albedo (mean 0.5) brought to the truth's (0.3)
    relit = report["views"]["relit"]
    # (one factor per channel; a flash is white, so the albedo's colour is the truth's and they agree)
    assert relit["albedo_scale"] == pytest.approx([np.mean(TRUE_ALBEDO) / convention.ALBEDO_CONVENTION] * 3, rel=0.1)
    assert relit["psnr"] > 20


def test_the_tracker_scores_a_flash_run_under_its_flash(flash_run):
    run, capture = flash_run
    series = json.loads((run / "report.json").read_text())["accuracy_time"]
    assert series["source"] == "ground truth" and len(series["points"]) >= 2
    psnrs = [p["psnr"] for p in series["points"]]
    black = unlit_psnr(run, capture)  # the tracker before the fix rendered the unlit views black too
    assert all(math.isfinite(p) for p in psnrs) and psnrs[-1] > black + 10, (psnrs, black)


# -- estimate: evaluate a short real run --------------------------------------------------------
ESTIMATE_SETTINGS = {"level_iterations": 15, "min_level_iterations": 5, "max_levels": 1, "polish_rounds": 0,
                     "time_budget_s": 30}
ESTIMATE_FAST = ["--max-size", "32", "--coarse-size", "32", "--initial-faces", "800", "--spp", "4",
                 "--effects", "specular"]


def test_evaluate_renders_an_estimate_run_under_its_fitted_map(tmp_path):
    hdr = shared_data("envmaps", "forest_slope_1k.hdr")
    capture, run = tmp_path / "capture", tmp_path / "run"
    run_cli("synth", "--out", capture, "--lighting", "env", "--env", hdr, "--views", 8, "--resolution", 32,
            "--spp", 32, "--held-out", 2, check=True)
    strip_light(capture)
    proc = run_cli("reconstruct", capture, "--out", run, "--lighting", "estimate", *ESTIMATE_FAST, timeout=400,
                   env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(ESTIMATE_SETTINGS)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = evaluate(run, capture)
    held, before = report["views"]["held_out"], unlit_psnr(run, capture)
    assert "fitted environment map" in held["lighting"]
    assert held["psnr"] > 18 and held["psnr"] > before + 10, (held["psnr"], before)
    scale = report["views"]["relit"]["albedo_scale"]
    assert len(scale) == 3 and min(scale) > 0
