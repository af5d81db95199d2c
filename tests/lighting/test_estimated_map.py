"""``--lighting estimate`` (backend.lighting.estimated_map, backend.lighting.modes): the map's
conventions, its fit with the material through real renders, and the command end to end on a
tiny capture rendered under an HDR map that the run does not get."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from backend import variant

variant.choose()

import mitsuba as mi  # noqa: E402

from backend.capture.images import read_linear_rgb, write_image, write_mask  # noqa: E402
from backend.capture.model import Capture, Environment, Frame  # noqa: E402
from backend.errors import InputError  # noqa: E402
from backend.lighting import convention, estimated_map  # noqa: E402
from backend.lighting.modes import resolve_lighting  # noqa: E402
from backend.material import stages  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer, environment_dict, sensor_dict  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402
from tests.helpers import REPO, run_cli, shared_data, withheld_map_capture  # noqa: E402

FOREST = ("envmaps", "forest_slope_1k.hdr")


def box_down(a: np.ndarray, w: int, h: int) -> np.ndarray:
    return np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(a[..., c], np.float32), "F")
                                .resize((w, h), Image.BOX)) for c in range(a.shape[-1])], -1)


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(np.log(a.mean(-1)).ravel(), np.log(b.mean(-1)).ravel())[0, 1])


def test_texel_directions_round_trip_and_upsample_wraps():
    d = estimated_map.directions(16, 8)
    rows, cols = estimated_map.texel_of(d.reshape(-1, 3), 16, 8)
    assert np.array_equal(rows.reshape(8, 16), np.repeat(np.arange(8)[:, None], 16, 1))
    assert np.array_equal(cols.reshape(8, 16), np.repeat(np.arange(16)[None, :], 8, 0))
    assert d[0, 0, 2] > 0.9 and d[-1, 0, 2] < -0.9  # row 0 is the zenith (Z up)
    latent = np.zeros((8, 16, 3), np.float32)
    latent[:, 0] = 1.0
    up = estimated_map.upsample(latent, 32, 16)
    assert up.shape == (16, 32, 3)
    assert up[:, -1, 0].mean() > 0.2 and up[:, 16, 0].max() == 0  # longitude wraps, the far side stays


def test_initial_map_is_the_background_seen_through_the_camera_rays(tmp_path):
    """Frames that show the environment directly (no object, empty masks) give back the map
    where the rays looked: the projection and the renderer's lookup agree."""
    sky = procedural.sky(64)
    env = Environment(tmp_path / "sky.exr", 1.0, 0.0)
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "path", "max_depth": 2},
                          "environment": environment_dict(env, sky)})
    cams = layout.orbit_cameras(layout.fibonacci_sphere(12), np.zeros(3), 0.5, 24)
    frames = []
    for k, cam in enumerate(cams):
        image = np.array(mi.render(scene, sensor=mi.load_dict(sensor_dict(cam, 16)), spp=16))
        write_image(tmp_path / f"{k}.exr", image)
        write_mask(tmp_path / f"{k}.png", np.zeros(image.shape[:2]))
        frames.append(Frame(str(k), tmp_path / f"{k}.exr", cam, mask=tmp_path / f"{k}.png"))
    pixels, source, seen, scale = estimated_map.initial_map(Capture(tmp_path, frames), 16, 8)
    assert source == "background" and 0.2 < seen < 1.0 and scale == 1.0  # no object seen: the level kept
    dirs, _, _ = estimated_map.background_samples(Capture(tmp_path, frames))
    rows, cols = estimated_map.texel_of(dirs, 16, 8)
    hit = np.zeros((8, 16), bool)
    hit[rows, cols] = True
    truth = box_down(sky, 16, 8)
    assert correlation(pixels[hit][None], truth[hit][None]) > 0.8


def test_frames_black_outside_their_masks_but_for_edge_leaks_show_no_background(tmp_path):
    """A synthetic frame whose object's anti-aliased edge leaks a few pixels past its mask is
    still a frame without a background: the map starts uniform, not from those pixels."""
    cams = layout.orbit_cameras(layout.fibonacci_sphere(4), np.zeros(3), 0.5, 24)
    frames = []
    for k, cam in enumerate(cams):
        image = np.zeros((24, 24, 3), np.float32)
        mask = np.zeros((24, 24))
        mask[6:18, 6:18] = 1
        image[mask > 0] = 0.6
        image[5, 6:18] = 0.01  # the edge leak: 12 of 432 background pixels
        write_image(tmp_path / f"{k}.exr", image)
        write_mask(tmp_path / f"{k}.png", mask)
        frames.append(Frame(str(k), tmp_path / f"{k}.exr", cam, mask=tmp_path / f"{k}.png"))
    pixels, source, seen, _ = estimated_map.initial_map(Capture(tmp_path, frames), 16, 8)
    assert source == "uniform" and seen == 0.0
    assert np.allclose(pixels, 0.6 / convention.ALBEDO_CONVENTION, rtol=1e-3)


def test_initial_map_level_lets_the_convention_albedo_render_the_object(tmp_path):
    """A dim background (a dark table) around a bright object: the map keeps the background's
    pattern and colour at the level where an albedo of 0.5 shows the object's brightness."""
    cams = layout.orbit_cameras(layout.fibonacci_sphere(6), np.zeros(3), 0.5, 24)
    frames = []
    for k, cam in enumerate(cams):
        image = np.empty((24, 24, 3), np.float32)
        image[:] = [0.06, 0.03, 0.01] if k % 2 else [0.03, 0.015, 0.005]  # a reddish backdrop, two shades
        mask = np.zeros((24, 24))
        mask[6:18, 6:18] = 1
        image[mask > 0] = [0.7, 0.65, 0.6]
        write_image(tmp_path / f"{k}.exr", image)
        write_mask(tmp_path / f"{k}.png", mask)
        frames.append(Frame(str(k), tmp_path / f"{k}.exr", cam, mask=tmp_path / f"{k}.png"))
    pixels, source, _, scale = estimated_map.initial_map(Capture(tmp_path, frames), 16, 8)
    assert source == "background" and scale > 10
    level = float(estimated_map.sphere_mean(pixels).mean())
    assert level * convention.ALBEDO_CONVENTION == pytest.approx(0.65, rel=0.05)
    seen = pixels.reshape(-1, 3)
    assert np.all(seen[:, 0] > seen[:, 1]) and np.all(seen[:, 1] > seen[:, 2])  # its colour kept


def test_environment_fit_recovers_the_sky_with_a_known_material():
    """Real renders: the map's latents fitted from uniform grey through Mitsuba's envmap data
    (with its wrapped columns) find the sky's bright side and the sun's azimuth."""
    mesh = procedural.blob(3)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(8), np.zeros(3), 0.6, 32)
    material = MeshColorMaterial(mesh, 1)
    material.set_values("albedo", [0.5, 0.5, 0.5])
    sky = procedural.sky(64)
    truth = SceneRenderer(mesh, material.field, cams, [[] for _ in cams], Environment(Path("sky.exr")),
                          RenderSettings(spp=64, max_depth=2, integrator="path"), env_pixels=sky, rgba=True)
    out = [truth.render_numpy(v, seed=v) for v in range(len(cams))]
    images, weights = [o[..., :3] for o in out], [o[..., 3] for o in out]
    fitted = estimated_map.EstimatedEnvironment(np.full((8, 16, 3), np.log(0.5), np.float32), Path("e.exr"))
    renderer = SceneRenderer(mesh, material.field, cams, [[] for _ in cams], fitted.environment(),
                             RenderSettings(spp=8, max_depth=2, integrator="prb"))
    before = stages.evaluate_loss(renderer, images, weights, material)
    stages.fit(renderer, images, weights, material, [], stages.FitSettings(iterations=40), lighting=fitted)
    after = stages.evaluate_loss(renderer, images, weights, material)
    assert after < 0.6 * before
    assert np.all(np.isfinite(fitted.pixels)) and fitted.pixels.min() > 0
    target = box_down(sky, 16, 8)
    assert correlation(fitted.pixels, target) > 0.5
    lum = fitted.pixels.mean(-1)
    assert lum[:4].mean() > 1.5 * lum[4:].mean()  # sky above, ground below
    assert abs(int(np.argmax(lum.max(0))) - int(np.argmax(target.mean(-1).max(0)))) <= 2  # the sun's azimuth


def test_restart_returns_the_map_to_its_initial_state(tmp_path):
    capture = Capture(tmp_path, [])
    env = estimated_map.EstimatedEnvironment.initial(capture, tmp_path / "environment.exr")
    first = env.latent.copy()
    env.at_stage("specular")
    env.latent = env.latent + 1.0
    env.restart(capture)
    assert env.level == 0 and env.resolution == estimated_map.RESOLUTIONS[0] and env.restarts == 1
    assert np.array_equal(env.latent, first) and env.report()["restarts"] == 1


def test_normalise_keeps_renders_and_sets_mean_albedo():
    mesh = procedural.blob(2)
    material = MeshColorMaterial(mesh, 1)
    material.set_values("albedo", [0.2, 0.3, 0.4])
    material.light_factor = 2.0
    fitted = estimated_map.EstimatedEnvironment(np.zeros((8, 16, 3), np.float32), Path("e.exr"))
    s = fitted.normalise(material)
    assert s == pytest.approx(0.5 / 0.3, rel=1e-4)
    assert convention.mean_albedo(material) == pytest.approx(0.5, rel=1e-3)
    assert material.light_factor == 1.0
    # albedo x light unchanged: 0.3 x (1 x 2) = 0.5 x radiance
    assert float(fitted.pixels.mean()) == pytest.approx(2.0 * 0.3 / 0.5, rel=1e-3)


def test_resolve_lighting_defaults_and_errors(tmp_path):
    dark = Capture(tmp_path, [])
    assert resolve_lighting(dark, None) == "auto"  # chosen by the probe (planning.lighting_choice)
    for mode in ("none", "captured"):
        with pytest.raises(InputError, match="no light source"):
            resolve_lighting(Capture(tmp_path, []), mode)
    lit = Capture(tmp_path, [], environment=Environment(tmp_path / "x.exr"))
    assert resolve_lighting(lit, None) == "captured" and lit.environment is not None
    assert resolve_lighting(lit, "estimate") == "estimate" and lit.environment is None  # withheld
    with pytest.raises(InputError, match="give one of them"):
        resolve_lighting(Capture(tmp_path, []), "estimate", env=str(tmp_path / "x.exr"))
    assert resolve_lighting(None, None, video_light=False) == "auto"
    with pytest.raises(InputError, match="give one of them"):
        resolve_lighting(Capture(tmp_path, []), "auto", env=str(tmp_path / "x.exr"))


@pytest.fixture(scope="module")
def dark_capture(tmp_path_factory) -> tuple[Path, Path]:
    """A capture rendered under the forest HDR map, and a copy of it without its environment."""
    return withheld_map_capture(tmp_path_factory.mktemp("lit"), 8, 32, 32, shared_data(*FOREST))


# relight_reserve 0: the relight runs whatever share of the budget a loaded machine has left
SMALL = {"level_iterations": 15, "min_level_iterations": 5, "max_levels": 1, "polish_rounds": 0, "time_budget_s": 30,
         "relight_reserve": 0.0}
FAST = ["--max-size", "32", "--coarse-size", "32", "--initial-faces", "800", "--spp", "4", "--effects", "specular"]


def test_capture_without_light_estimates_the_map(dark_capture, tmp_path):
    # named: the default (auto) probes first (tests/lighting/test_choice.py), which a 30 s budget
    # would pay for with the relight this test follows
    dark, true_map = dark_capture
    run = tmp_path / "run"
    proc = run_cli("reconstruct", dark, "--out", run, "--lighting", "estimate", *FAST, timeout=400,
                   env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(SMALL)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert log[-1]["event"] == "done"
    assert log[0]["settings"]["lighting"] == "estimate"
    assert not [e for e in log if e["event"] == "lighting_choice"]  # named: no probe
    lighting = [e for e in log if e["event"] == "lighting"]
    assert lighting[0]["when"] == "initial" and any(e["when"] == "fitted" for e in lighting)
    # the map is fitted on the initial mesh before the surface moves (appearance.light_first)
    stages = [e["stage"] for e in log if e["event"] == "stage"]
    assert stages.index("material:constant") < stages.index("geometry")
    whole = json.loads((run / "report.json").read_text())
    first = whole["init"]["light_first"]
    assert 1 <= first["cycles"] <= 3 and len(first["losses"]) == first["cycles"]
    # once geometry has converged the map and the material restart and are fitted again on the
    # final surface (Appearance.finalise): constants first, after the last geometry step
    order = [(e["event"], e.get("when") or e.get("stage")) for e in log if e["event"] in ("lighting", "stage")]
    restart = order.index(("lighting", "restarted"))
    last_geometry = max(i for i, x in enumerate(order) if x == ("stage", "geometry"))
    assert restart > last_geometry and order[restart + 1] == ("stage", "material:constant")
    assert whole["lighting"]["restarts"] == 1
    # judged once the final stages end (optimize/relight.py): kept, or the earlier fit put back
    relight = whole["lighting"]["relight"]
    assert relight["kept"] == (relight["loss_after"] <= relight["tolerance"] * relight["loss_before"])
    assert ("lighting", "relit" if relight["kept"] else "restored") in order[restart:]
    report = whole["lighting"]
    assert report["model"].startswith("environment map") and "mean albedo" in report["scale_convention"]
    fitted = read_linear_rgb(run / "environment.exr")
    assert fitted.shape[:2][::-1] == tuple(report["resolution"])
    assert np.all(np.isfinite(fitted)) and fitted.min() > 0
    truth = box_down(read_linear_rgb(true_map), fitted.shape[1], fitted.shape[0])
    assert correlation(fitted, truth) > 0.3


def test_a_cancel_during_the_relight_judges_it_before_the_last_snapshot(dark_capture, tmp_path):
    dark, _ = dark_capture
    run = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1", SFT_RECONSTRUCT_SETTINGS=json.dumps(SMALL))
    proc = subprocess.Popen([sys.executable, "-m", "backend", "reconstruct", str(dark), "--out", str(run), *FAST],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
    events = []
    for line in proc.stdout:
        events.append(json.loads(line))
        if events[-1]["event"] == "lighting" and events[-1]["when"] == "restarted":
            (run / "STOP").touch()  # checked at the relight's next progress event
    proc.communicate(timeout=300)
    assert proc.returncode == 130
    kinds = [(e["event"], e.get("when")) for e in events]
    restart, cancelled = kinds.index(("lighting", "restarted")), kinds.index(("cancelled", None))
    judged = [i for i, k in enumerate(kinds) if k in (("lighting", "relit"), ("lighting", "restored"))]
    assert len(judged) == 1 and restart < judged[0] < cancelled
    assert events[cancelled]["snapshot"] and (run / "environment.exr").is_file()


def test_lighting_none_without_light_is_a_one_line_error(dark_capture, tmp_path):
    dark, _ = dark_capture
    proc = run_cli("reconstruct", dark, "--out", tmp_path / "run", "--lighting", "none", timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "no light source" in lines[0]
