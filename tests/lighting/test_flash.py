"""``--lighting flash`` (backend.lighting.flash, backend.lighting.modes): a point light at every
camera, its intensity fitted through real renders with the material, the albedo x light
scale settled by the mean-albedo convention; ``synth --lighting flash`` renders the test
captures; the command end to end on a tiny flash-lit capture that carries no lights."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.load import load_capture  # noqa: E402
from backend.capture.model import Capture, Environment, Frame  # noqa: E402
from backend.errors import InputError  # noqa: E402
from backend.lighting import convention, flash  # noqa: E402
from backend.lighting.modes import resolve_lighting  # noqa: E402
from backend.material import stages  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402
from tests.helpers import run_cli  # noqa: E402

TRUE_INTENSITY = 2.0  # W/sr
TRUE_ALBEDO = (0.4, 0.3, 0.2)  # mean 0.3


@pytest.fixture(scope="module")
def flash_capture(tmp_path_factory) -> tuple[Path, Path]:
    """A diffuse object rendered under a flash of ``TRUE_INTENSITY`` at each camera, and a copy
    of it whose capture.json names no lights (as a DTU-like capture would)."""
    root = tmp_path_factory.mktemp("flash")
    run_cli("synth", "--out", root / "lit", "--lighting", "flash", "--light-intensity", TRUE_INTENSITY,
            "--albedo", ",".join(map(str, TRUE_ALBEDO)), "--specular", 0, "--views", 8, "--resolution", 32,
            "--spp", 32, "--held-out", 0, check=True)
    shutil.copytree(root / "lit", root / "dark")
    data = json.loads((root / "dark" / "capture.json").read_text())
    for frame in data["frames"]:
        frame.pop("lights")
    (root / "dark" / "capture.json").write_text(json.dumps(data))
    return root / "lit", root / "dark"


def test_synth_flash_puts_one_light_at_each_camera(flash_capture):
    lit = load_capture(flash_capture[0])
    assert all(len(f.lights) == 1 for f in lit.frames)
    for frame in lit.frames:
        assert np.allclose(frame.lights[0].position, frame.camera.centre)
        assert np.allclose(frame.lights[0].intensity, TRUE_INTENSITY)
    assert not load_capture(flash_capture[1]).has_point_lights


def test_initial_intensity_is_the_flash_that_renders_the_frames_at_mean_albedo_half(flash_capture):
    """The starting guess, before any render: within 25 % of the intensity at which albedo 0.5
    gives the frames' brightness (truth x mean albedo / 0.5)."""
    guess = flash.initial_intensity(load_capture(flash_capture[1]))
    equivalent = TRUE_INTENSITY * np.mean(TRUE_ALBEDO) / convention.ALBEDO_CONVENTION
    assert guess == pytest.approx(equivalent, rel=0.25)


@pytest.fixture(scope="module")
def known_scene():
    """Renders of the built-in object (known material) under a flash of 1.5 W/sr at each camera."""
    mesh = procedural.blob(3)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(6), np.zeros(3), 0.6, 32)
    material = MeshColorMaterial(mesh, 1)
    material.set_values("albedo", [0.6, 0.5, 0.4])
    material.set_values("specular", [0.2])
    truth = SceneRenderer(mesh, material.field, cams, [layout.flash_light(c, 1.5) for c in cams], None,
                          RenderSettings(spp=64, max_depth=2, integrator="path"), rgba=True)
    out = [truth.render_numpy(v, seed=v) for v in range(len(cams))]
    return mesh, cams, material, [o[..., :3] for o in out], [o[..., 3] for o in out]


def fit_flash(known_scene, tmp_path, start: float, iterations: int = 40):
    """The flash fitted from ``start`` W/sr with the material held: (its model, the capture's
    frames, losses before and after, the renderer)."""
    mesh, cams, material, images, weights = known_scene
    capture = Capture(tmp_path, [Frame(str(k), tmp_path / f"{k}.exr", c) for k, c in enumerate(cams)])
    fitted = flash.Flash(capture, [math.log(start)])
    renderer = SceneRenderer(mesh, material.field, cams, [f.lights for f in capture.frames], None,
                             RenderSettings(spp=8, max_depth=2, integrator="prb"))
    before = stages.evaluate_loss(renderer, images, weights, material)
    stages.fit(renderer, images, weights, material, [], stages.FitSettings(iterations=iterations, views_per_step=2),
               lighting=fitted)
    return fitted, capture, before, stages.evaluate_loss(renderer, images, weights, material), renderer


def test_flash_fit_recovers_the_intensity_with_a_known_material(known_scene, tmp_path):
    """Real renders: with the material known and held, a stage's fit from 3x the truth (the
    closed-form start, then Adam) comes back to it, and the frames' lights carry the result."""
    fitted, capture, before, after, renderer = fit_flash(known_scene, tmp_path, 4.5)
    assert after < 0.01 * before
    assert fitted.intensity == pytest.approx(1.5, rel=0.03)
    assert all(np.allclose(f.lights[0].intensity, fitted.intensity) for f in capture.frames)
    assert renderer.light_scale is None  # the renderer reads the frames' lights again


def test_adam_alone_moves_the_intensity_through_the_light_scale(known_scene, tmp_path, monkeypatch):
    """Without the closed-form start, the gradients through the renderer's light scale (one
    backward pass per view) bring the log intensity from half the truth to it."""
    monkeypatch.setattr(flash.FlashFit, "prepare", lambda *args: None)
    fitted, _, before, after, _ = fit_flash(known_scene, tmp_path, 0.75)
    assert after < 0.05 * before
    assert fitted.intensity == pytest.approx(1.5, rel=0.06)


def test_normalise_keeps_albedo_times_intensity_and_sets_mean_albedo(tmp_path):
    mesh = procedural.blob(2)
    material = MeshColorMaterial(mesh, 1)
    material.set_values("albedo", [0.2, 0.3, 0.4])
    cams = layout.orbit_cameras(layout.fibonacci_sphere(3), np.zeros(3), 0.6, 8)
    capture = Capture(tmp_path, [Frame(str(k), tmp_path / f"{k}.exr", c) for k, c in enumerate(cams)])
    fitted = flash.Flash(capture, [math.log(3.0)])
    s = fitted.normalise(material)
    assert s == pytest.approx(0.5 / 0.3, rel=1e-4)
    assert convention.mean_albedo(material) == pytest.approx(0.5, rel=1e-3)
    assert fitted.intensity * 0.5 == pytest.approx(3.0 * 0.3, rel=1e-4)
    assert np.allclose(capture.frames[0].lights[0].intensity, fitted.intensity)
    report = fitted.report()
    assert report["model"] == "flash" and "mean albedo" in report["scale_convention"]
    assert report["albedo_scales"] == [round(s, 6)]
    resumed = flash.Flash(capture, [0.0])  # a resumed run: the intensity comes back from the state
    resumed.restore(fitted.state())
    assert resumed.intensity == pytest.approx(fitted.intensity)
    again = flash.Flash(capture, [math.log(3.0)], initial=2.0)  # the relight on the final surface
    again.normalise(material)
    again.restart()
    assert again.intensity == pytest.approx(2.0) and again.restarts == 1
    assert np.allclose(capture.frames[0].lights[0].intensity, 2.0)


def test_resolve_lighting_flash_replaces_the_lights_and_refuses_a_map(tmp_path):
    cams = layout.orbit_cameras(layout.fibonacci_sphere(3), np.zeros(3), 0.6, 8)
    frames = [Frame(str(k), tmp_path / f"{k}.exr", c, lights=layout.paper_lights(c, 5.0)) for k, c in enumerate(cams)]
    capture = Capture(tmp_path, frames, environment=Environment(tmp_path / "x.exr"))
    assert resolve_lighting(capture, "flash") == "flash"
    assert capture.environment is None  # withheld: the flash is the only light
    for frame in capture.frames:
        assert len(frame.lights) == 1 and np.allclose(frame.lights[0].position, frame.camera.centre)
    dark = Capture(tmp_path, [Frame("0", tmp_path / "0.exr", cams[0])])
    assert resolve_lighting(dark, "flash") == "flash" and dark.has_point_lights  # added where there were none
    with pytest.raises(InputError, match="--lighting flash") as err:
        resolve_lighting(Capture(tmp_path, []), "flash", env=str(tmp_path / "x.exr"))
    assert "drop --env" in str(err.value)


SETTINGS = {"max_levels": 1, "polish_rounds": 0}
FAST = ["--iterations", "20", "--max-size", "16", "--coarse-size", "16", "--initial-faces", "800", "--spp", "4",
        "--effects=-specular"]


def test_reconstruct_with_a_flash_fits_its_intensity(flash_capture, tmp_path):
    """The capture names no light; ``--lighting flash`` puts one at every camera and fits its
    intensity with the material: under the convention (mean albedo 0.5) the fitted intensity
    x 0.5 is the true intensity x the true mean albedo (what the images fix)."""
    run = tmp_path / "run"
    proc = run_cli("reconstruct", flash_capture[1], "--out", run, "--lighting", "flash", *FAST, timeout=300,
                   env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(SETTINGS)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert log[-1]["event"] == "done" and log[0]["settings"]["lighting"] == "flash"
    lighting = [e for e in log if e["event"] == "lighting"]
    assert lighting[0]["when"] == "initial" and lighting[0]["model"] == "flash"
    fitted = [e for e in lighting if e["when"] == "fitted"]
    assert fitted and fitted[-1]["albedo_scale"] is not None
    report = json.loads((run / "report.json").read_text())
    assert report["lighting"]["model"] == "flash" and "mean albedo" in report["lighting"]["scale_convention"]
    assert report["lighting"]["intensity"] == fitted[-1]["intensity"]
    product = report["lighting"]["intensity"] * convention.ALBEDO_CONVENTION
    assert product == pytest.approx(TRUE_INTENSITY * np.mean(TRUE_ALBEDO), rel=0.1)
    albedo = np.asarray(report["material"]["albedo"]).mean()
    assert albedo == pytest.approx(convention.ALBEDO_CONVENTION, rel=0.02)


def test_flash_with_an_hdr_map_is_a_one_line_error(flash_capture, tmp_path):
    proc = run_cli("reconstruct", flash_capture[1], "--out", tmp_path / "run", "--lighting", "flash",
                   "--env", tmp_path / "any.exr", timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--lighting flash" in lines[0] and "--env" in lines[0] and "Fix:" in lines[0]
    assert not (tmp_path / "run").exists()
