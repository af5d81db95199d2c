"""Per-frame exposure and white balance (backend.lighting.exposure, ``--exposure``) and the
albedo's scale (backend.lighting.convention.AlbedoScale, ``--known-albedo``,
``--map-calibrated``): the closed-form gains and their gauge, the material fitted on the true
surface of a capture whose frames carry known per-frame gains, and the command end to end."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.images import read_linear_rgb, write_image  # noqa: E402
from backend.capture.load import load_capture  # noqa: E402
from backend.capture.model import Capture  # noqa: E402
from backend.geometry.mesh import load_mesh  # noqa: E402
from backend.lighting import exposure  # noqa: E402
from backend.lighting.convention import ALBEDO_CONVENTION, mean_albedo, median_albedo  # noqa: E402
from backend.lighting.modes import resolve_lighting  # noqa: E402
from backend.material.stages import evaluate_loss  # noqa: E402
from backend.optimize.appearance import Appearance  # noqa: E402
from backend.optimize.config import ReconstructConfig  # noqa: E402
from backend.optimize.views import ViewSet  # noqa: E402
from tests.helpers import run_cli  # noqa: E402

ALBEDO = np.array([0.6, 0.45, 0.3])
SIZE = 32
VIEWS = 8


def _geomean(gains: np.ndarray) -> np.ndarray:
    return np.exp(np.log(gains).mean(0))


def test_solve_recovers_multiplicative_gains_up_to_the_gauge():
    rng = np.random.default_rng(0)
    renders = [rng.uniform(0.05, 1.0, (12, 10, 3)) for _ in range(6)]
    gains = rng.uniform(0.7, 1.3, (6, 3))
    targets = [r * g for r, g in zip(renders, gains)]
    weights = [np.ones((12, 10)) for _ in renders]
    fit = exposure.Exposure([str(i) for i in range(6)], prior=0.0)
    got = fit.solve(renders, targets, weights)
    assert np.allclose(np.log(got).mean(0), 0.0, atol=1e-12), "the gauge: mean log-gain 0 per channel"
    assert np.allclose(got, gains / _geomean(gains), rtol=1e-9)
    # the prior pulls each log-gain towards the median by 1 / (1 + lambda)
    shrunk = exposure.Exposure([str(i) for i in range(6)], prior=0.25).solve(renders, targets, weights)
    log = np.log(gains)
    expected = (log - np.median(log, 0)) / 1.25
    assert np.allclose(np.log(shrunk), expected - expected.mean(0), atol=1e-9)
    # a frame with no pixels takes the median; the corrected target is the frame over its gain
    weights[2] = np.zeros((12, 10))
    fit.solve(renders, targets, weights)
    a = log - np.median(log[[0, 1, 3, 4, 5]], 0)
    a[2] = 0.0
    assert np.allclose(fit.latent, a - a.mean(0), atol=1e-9)
    assert np.allclose(fit.correct(1, targets[1]), targets[1] / fit.gains[1], rtol=1e-6)


def test_auto_fits_captures_from_a_video_or_photos_only(tmp_path):
    def capture(**provenance):
        return Capture(tmp_path, [], provenance=provenance)

    for source in ("synth", "bench", "idr", "colmap", None):  # rendered, or a dataset shot with fixed settings
        assert not exposure.enabled("auto", capture(source=source))
    for source in ("video", "images"):  # capture-from-video: a phone's frames
        assert exposure.enabled("auto", capture(source=source))
    assert exposure.enabled("per-frame", capture(source="synth"))
    assert not exposure.enabled("off", capture(source="video"))
    with pytest.raises(ValueError):
        exposure.enabled("always", capture())


@pytest.fixture(scope="module")
def gained(tmp_path_factory):
    """A diffuse object of albedo ``ALBEDO`` under point lights; a copy whose frames are
    multiplied by random per-frame gains in [0.7, 1.3] per channel, and one whose frames all
    carry those gains' geometric mean (the same scale under the gauge, one exposure)."""
    root = tmp_path_factory.mktemp("exposure")
    run_cli("synth", "--out", root / "base", "--views", VIEWS, "--resolution", SIZE, "--spp", 32, "--held-out", 0,
            "--albedo", ",".join(map(str, ALBEDO)), "--specular", 0, check=True)
    gains = np.random.default_rng(1).uniform(0.7, 1.3, (VIEWS, 3))
    for name, g in (("gained", gains), ("constant", np.tile(_geomean(gains), (VIEWS, 1)))):
        shutil.copytree(root / "base", root / name)
        for frame, gi in zip(load_capture(root / name).frames, g):
            write_image(frame.image, read_linear_rgb(frame.image) * gi.astype(np.float32))
    return root, gains


def _fit(folder: Path, mode: str, cycles: int = 4, **settings):
    """The staged material fitted on the true surface by ``cycles`` material cycles (the gains
    solved after each, as a run does); (appearance, material, residual on the views it fits)."""
    capture = load_capture(folder)
    if settings.get("lighting") == "flash":
        resolve_lighting(capture, "flash")  # a light at every camera, as the command sets it
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    config = ReconstructConfig(material="staged", exposure=mode, spp=8, max_size=SIZE, **settings)
    appearance = Appearance(capture, config, lambda *a, **k: None)
    viewset = ViewSet(capture, SIZE)
    appearance.use_views(viewset)
    appearance.start_lighting(folder)
    material = appearance.initial_material(mesh, viewset.at(SIZE))
    for _ in range(cycles):
        appearance.material_cycle(mesh, material, viewset.at(SIZE), 0)
    views = viewset.at(SIZE)
    residual = evaluate_loss(appearance._renderer(mesh, material, views, geometry=False), [v.target for v in views],
                             [v.mask for v in views], material)
    return appearance, material, residual


def _albedo_error(material, truth) -> float:
    return float(np.abs(material.values("albedo").reshape(-1, 3).mean(0) / truth - 1).mean())


def test_per_frame_gains_are_recovered_and_the_albedo_keeps_its_accuracy(gained):
    root, gains = gained
    truth = ALBEDO * _geomean(gains)  # the gauge: the gains' geometric mean is 1, the albedo carries the rest
    on, material_on, residual_on = _fit(root / "gained", "per-frame")
    fitted = on.exposure.exposure.gains
    assert np.abs(fitted / (gains / _geomean(gains)) - 1).max() < 0.05
    _, material_off, residual_off = _fit(root / "gained", "off")
    _, material_constant, _ = _fit(root / "constant", "off")
    error_on, error_off = _albedo_error(material_on, truth), _albedo_error(material_off, truth)
    assert error_on <= _albedo_error(material_constant, truth) + 0.01
    assert error_off > error_on and residual_off > 2 * residual_on, (error_off, error_on, residual_off, residual_on)
    report = on.exposure.exposure.report()
    assert report["convention"] == exposure.CONVENTION and len(report["gains"]) == VIEWS


def test_known_albedo_sets_the_median_level_and_the_default_the_mean(gained):
    root, _ = gained
    for known, check in ((None, lambda m: mean_albedo(m) == pytest.approx(ALBEDO_CONVENTION, rel=1e-3)),
                         ((0.3, 0.2, 0.1), lambda m: median_albedo(m).mean() == pytest.approx(0.2, rel=1e-3))):
        appearance, material, _ = _fit(root / "base", "off", cycles=2, lighting="flash", known_albedo=known)
        assert check(material)
        report = appearance.albedo_scale_report(material)
        assert report["mode"] == ("known" if known else "mean") and "median_albedo" in report
        assert ("known albedo" in report["convention"]) == bool(known)


@pytest.fixture(scope="module")
def env_capture(tmp_path_factory):
    out = tmp_path_factory.mktemp("env") / "capture"
    run_cli("synth", "--out", out, "--views", 6, "--resolution", 24, "--spp", 16, "--held-out", 0, "--lighting", "env",
            "--env", "sky", "--env-strength", 0.8, "--albedo", ",".join(map(str, ALBEDO)), "--specular", 0, check=True)
    return out


def test_a_calibrated_map_keeps_its_strength(env_capture):
    """With ``--map-calibrated`` the map's brightness factor is never fitted (k stays 1), so
    the albedo's scale is the map's; without it, the first texture stage fits k."""
    appearance, material, _ = _fit(env_capture, "off", cycles=5, map_calibrated=True)
    assert material.light_factor == 1.0
    assert material.channels["albedo"].kind == "colors", "a texture stage ran"
    assert appearance.albedo_scale_report(material)["mode"] == "map"
    assert np.abs(median_albedo(material) / ALBEDO - 1).max() < 0.15, "the true map sets the true albedo"
    appearance, material, _ = _fit(env_capture, "off", cycles=5)
    assert material.light_factor != 1.0 and appearance.albedo_scale_report(material)["mode"] == "light factor"


SETTINGS = {"max_levels": 1, "polish_rounds": 0}
FAST = ["--iterations", "20", "--max-size", "16", "--coarse-size", "16", "--initial-faces", "800", "--spp", "4",
        "--effects=-specular"]


def test_reconstruct_reports_the_gains_and_the_scale(gained, tmp_path):
    root, _ = gained
    run = tmp_path / "run"
    proc = run_cli("reconstruct", root / "gained", "--out", run, "--exposure", "per-frame", "--lighting", "flash",
                   "--known-albedo", "0.3,0.2,0.1", *FAST, timeout=300, env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(SETTINGS)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads((run / "report.json").read_text())
    assert report["settings"]["exposure"] == "per-frame"
    gains = report["exposure"]["gains"]
    assert len(gains) == VIEWS and report["exposure"]["solves"] >= 1
    assert np.allclose(np.log(np.array(list(gains.values()))).mean(0), 0.0, atol=1e-4)
    assert report["albedo_scale"]["mode"] == "known" and "known albedo" in report["lighting"]["scale_convention"]
    for args, words in ((["--known-albedo", "0.3,2"], "--known-albedo must be three"),
                        (["--map-calibrated", "--lighting", "flash"], "--map-calibrated keeps a captured map")):
        proc = run_cli("reconstruct", root / "gained", "--out", tmp_path / "bad", *args, *FAST)
        assert proc.returncode == 2 and words in proc.stderr and "Traceback" not in proc.stderr, proc.stderr[-2000:]
        assert len(proc.stderr.strip().splitlines()) == 1 and not (tmp_path / "bad").exists()
