"""The final texture stage: resolution from the frames' pixel footprint, and a fit at the
frames' own size that renders the fitted views better than the run's material did."""

import argparse
import io
import json

import numpy as np
from PIL import Image

from backend import variant

variant.choose()

from backend.capture.format import save_capture  # noqa: E402
from backend.capture.images import write_image, write_mask  # noqa: E402
from backend.capture.model import Camera, Capture, Frame  # noqa: E402
from backend.commands import reconstruct  # noqa: E402
from backend.errors import InputError  # noqa: E402
from backend.geometry.mesh import Mesh  # noqa: E402
from backend.geometry.primitives import icosphere  # noqa: E402
from backend.render.fields import VertexField  # noqa: E402
from backend.material import export  # noqa: E402
from backend.material.export import read_glb  # noqa: E402
from backend.material.footprint import face_footprints, footprint_resolutions  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.material.stages import FitSettings, fit  # noqa: E402
from backend.metrics.image import psnr  # noqa: E402
from backend.optimize.appearance import Appearance  # noqa: E402
from backend.optimize.budget import TEXTURE_RESERVE, Budget  # noqa: E402
from backend.optimize.config import ReconstructConfig  # noqa: E402
from backend.optimize.records import RunState  # noqa: E402
from backend.optimize.texture_stage import TextureStage  # noqa: E402
from backend.optimize.views import ViewSet  # noqa: E402
from backend.planning.job import config_from_args  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout  # noqa: E402
from tests.helpers import run_cli  # noqa: E402

SIZE, FIT_SIZE, RADIUS = 96, 32, 0.5


def test_footprint_gives_finer_resolution_to_faces_closer_to_the_camera():
    """Two equal triangles facing the camera, one twice as far: half the pixels, half the r."""
    tri = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.3, 0.0]])
    near, far = tri + [-0.5, 0.0, -2.0], tri + [0.2, 0.0, -4.0]
    mesh = Mesh(np.vstack([near, far]), np.array([[0, 1, 2], [3, 4, 5]]))
    camera = Camera(200, 200, 100.0, 100.0, 100.0, 100.0, np.eye(4))  # at the origin, looking down -z
    footprint = face_footprints(mesh, [camera])
    assert abs(footprint[0] - 100 * 0.3 * np.sqrt(2) / 2.0) < 1.0 and abs(footprint[0] / footprint[1] - 2.0) < 0.1
    r = footprint_resolutions(footprint)
    assert r[0] > r[1] >= 1 and abs(r[0] - round(footprint[0])) <= 1
    assert np.array_equal(footprint_resolutions([0.0, 500.0]), [1, 32])  # unseen: 1; clamped at the top
    # a face no view sees has no footprint (a camera looking away)
    behind = Camera(200, 200, 100.0, 100.0, 100.0, 100.0, np.diag([-1.0, 1.0, -1.0, 1.0]))
    assert np.all(face_footprints(mesh, [behind]) == 0)


def checker(points: np.ndarray, cells: float = 7.0) -> np.ndarray:
    """A colour checker on the sphere (cells per unit along each axis)."""
    k = np.floor(points * cells / RADIUS).astype(int).sum(1) % 2
    return np.where(k[:, None] == 1, [0.75, 0.3, 0.15], [0.15, 0.45, 0.7]).astype(np.float32)


def sphere_capture(root) -> Capture:
    """8 views at SIZE px of a sphere with a fine checker albedo (per vertex of a fine mesh)."""
    truth = icosphere(5, RADIUS)
    field = VertexField(truth.faces, checker(truth.vertices), np.full(truth.n_vertices, 0.0),
                        np.full(truth.n_vertices, 0.5))
    cams = layout.orbit_cameras(layout.fibonacci_sphere(8), np.zeros(3), RADIUS, SIZE)
    lights = [layout.paper_lights(c, 0.6 * float(np.linalg.norm(c.centre)) ** 2) for c in cams]
    renderer = SceneRenderer(truth, field, cams, lights, None, RenderSettings(spp=64, max_depth=2, integrator="path",
                                                                              hide_emitters=True), rgba=True)
    frames = []
    for i, cam in enumerate(cams):
        rgba = renderer.render_numpy(i, seed=i)
        write_image(root / "images" / f"{i:04d}.exr", rgba[..., :3])
        write_mask(root / "masks" / f"{i:04d}.png", rgba[..., 3])
        frames.append(Frame(f"{i:04d}", root / "images" / f"{i:04d}.exr", cam, mask=root / "masks" / f"{i:04d}.png",
                            lights=lights[i]))
    capture = Capture(root, frames, None)
    save_capture(capture)
    return capture


def fitted_psnr(mesh, material, views) -> float:
    renderer = SceneRenderer(mesh, material.field, [v.camera for v in views], [v.lights for v in views], None,
                             RenderSettings(spp=64, max_depth=2, integrator="prb"))
    return float(np.mean([psnr(renderer.render_numpy(i, seed=50 + i)[..., :3], v.target, v.mask)
                          for i, v in enumerate(views)]))


def test_the_texture_stage_raises_the_fitted_views_psnr(tmp_path):
    capture = sphere_capture(tmp_path / "capture")
    config = ReconstructConfig(material="staged", max_size=FIT_SIZE, spp=8, max_depth=2, texture_iterations=40)
    mesh = icosphere(2, RADIUS)
    # the run without the stage: mesh colors at r = 2 fitted to the frames at the fit's size
    material = MeshColorMaterial(mesh, 2)
    material.make_spatial("albedo")
    coarse = ViewSet(capture, FIT_SIZE).views
    renderer = SceneRenderer(mesh, material.field, [v.camera for v in coarse], [v.lights for v in coarse], None,
                             RenderSettings(spp=8, max_depth=2, integrator="prb"))
    fit(renderer, [v.target for v in coarse], [v.mask for v in coarse], material, ["albedo"],
        FitSettings(iterations=40, lr=0.1))
    full = ViewSet(capture, SIZE).views
    before = fitted_psnr(mesh, material, full)

    events = []
    stage = TextureStage(capture, config, staged=True)
    assert stage.enabled and stage.size == SIZE and "larger" in stage.record["reason"]
    budget = Budget(config, RunState(), staged=True)
    budget.texture_share = stage.reserve_share()
    record = stage.run(mesh, material, Appearance(capture, config, lambda *a, **k: None), budget,
                       lambda name, **fields: events.append((name, fields)))
    after = fitted_psnr(mesh, material, full)
    assert record["kept"] and record["image_size"] == [SIZE, SIZE] and record["fit_size"] == FIT_SIZE
    assert budget.texture_share == 0.0
    assert not material.layout.uniform and record["resolution"]["max"] > 2
    assert record["loss_after"] < record["loss_before"]
    assert after > before + 1.0, (before, after)
    assert [n for n, _ in events if n in ("stage", "texture")] == ["stage", "texture"]


def test_the_stage_reserve_is_sized_by_a_timed_render(tmp_path):
    """With a time budget, the share held for the stage becomes its expected time once the
    levels end (one render timed at its size), not the fixed TEXTURE_RESERVE."""
    capture = sphere_capture(tmp_path / "capture")
    config = ReconstructConfig(material="staged", max_size=FIT_SIZE, spp=8, max_depth=2, texture_iterations=30,
                               time_budget_s=600.0)
    mesh = icosphere(2, RADIUS)
    material = MeshColorMaterial(mesh, 2)
    stage = TextureStage(capture, config, staged=True)
    budget = Budget(config, RunState(), staged=True)
    budget.texture_share = stage.reserve_share()
    appearance = Appearance(capture, config, lambda *a, **k: None)
    stage.size_reserve(mesh, material, appearance, budget)
    reserve = stage.record["reserve"]
    assert 0.0 < budget.texture_share < TEXTURE_RESERVE and reserve["share"] == round(budget.texture_share, 4)
    assert reserve["render_s"] > 0 and budget.texture_share * 600.0 >= reserve["expected_s"]
    stage.size_reserve(mesh, material, appearance, budget)  # once per run: the first sizing stays
    assert stage.record["reserve"] is reserve
    record = stage.run(mesh, material, appearance, budget, lambda *a, **k: None)
    assert record["iterations"] == 30 and budget.texture_share == 0.0
    # the timed render predicts the stage: what it took is within a factor of two of the estimate
    assert 0.5 * reserve["expected_s"] <= record["seconds"] <= 2.0 * reserve["expected_s"], (record, reserve)


def test_auto_runs_the_stage_only_for_frames_larger_than_the_fit(tmp_path):
    frames = [Frame("a", tmp_path / "a.png", Camera(64, 48, 60.0, 60.0, 32.0, 24.0, np.eye(4)))]
    capture = Capture(tmp_path, frames, None)
    assert TextureStage(capture, ReconstructConfig(max_size=32), staged=True).enabled
    assert not TextureStage(capture, ReconstructConfig(max_size=64), staged=True).enabled
    assert TextureStage(capture, ReconstructConfig(max_size=64, texture_stage="on"), staged=True).enabled
    assert not TextureStage(capture, ReconstructConfig(max_size=32, texture_stage="off"), staged=True).enabled
    assert not TextureStage(capture, ReconstructConfig(max_size=32), staged=False).enabled
    capped = TextureStage(capture, ReconstructConfig(max_size=32, texture_size=48), staged=True)
    assert capped.size == 48 and capped.reserve_share() > 0


def test_the_command_line_switches_the_stage():
    parser = argparse.ArgumentParser()
    reconstruct.add_arguments(parser)
    config = config_from_args(parser.parse_args(["cap", "--out", "run"]))
    assert config.texture_stage == "auto" and config.texture_size is None
    config = config_from_args(parser.parse_args(["cap", "--out", "run", "--texture-stage", "off", "--texture-size", "512"]))
    assert config.texture_stage == "off" and config.texture_size == 512
    try:
        config_from_args(parser.parse_args(["cap", "--out", "run", "--texture-size", "0"]))
    except InputError as err:
        assert "--texture-size" in str(err)
    else:
        raise AssertionError("--texture-size 0 was accepted")


def test_a_run_ends_with_the_stage_and_exports_its_texture(tiny_capture, tmp_path):
    """``reconstruct`` on 48 px frames fitted at 24 px: the stage runs (auto), its record and
    the sizes of every stage are in report.json, and the glTF atlas follows the finest faces."""
    run = tmp_path / "run"
    proc = run_cli("reconstruct", tiny_capture, "--out", run, "--max-size", 24, "--coarse-size", 24,
                   "--initial-faces", 400, "--iterations", 20, "--max-levels", 1, "--level-iterations", 20,
                   "--spp", 4, "--material", "staged", timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads((run / "report.json").read_text())
    stage = report["texture_stage"]
    assert stage["enabled"] and stage["ran"] and stage["image_size"] == [48, 48] and stage["fit_size"] == 24
    assert stage["sizes"]["levels"] == [24] and stage["sizes"]["final_material"] == 24
    assert stage["kept"] and stage["loss_after"] < stage["loss_before"] and stage["sizes"]["texture"] == 48
    assert report["material"]["resolutions"]["max"] == stage["resolution"]["max"]
    # the saved material has the stage's per-face resolutions, and the atlas packs their cells
    material = MeshColorMaterial.load(sorted((run / "state").glob("*.material.npz"))[-1])
    assert not material.layout.uniform and material.resolution == stage["resolution"]["max"]
    _, _, width, height = export.pack_cells(export.cell_sizes(material))
    gltf, blob = read_glb(run / "result.glb")
    view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    png = Image.open(io.BytesIO(blob[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]))
    assert png.size == (width, height)
    log = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    assert any(e["event"] == "stage" and e["stage"] == "texture" for e in log)
    assert any(e["event"] == "texture" for e in log)
