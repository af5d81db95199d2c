"""Relit Preview under the run's own lighting, for every Lighting mode: the captured lights,
the estimated map (world-fixed, or fixed to the camera and turned with it), the fitted flash,
from a finished run's report.json or a running one's command line and events; Cycles renders
a sphere at 32 px with a few samples."""

from __future__ import annotations

import json

import bpy
import numpy as np
import pytest
from PIL import Image

from backend.geometry.mesh import save_mesh
from backend.geometry.primitives import icosphere

from .media import write_image
from .test_capture_ops import expect_error

SIZE = 32
# a camera on world -y looking at the origin (+y), up +z: Blender camera axes as columns
CAMERA_TO_WORLD = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, -4.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
FLASH = 20.0  # W/sr


def _looking_at_origin(position, up) -> list[list[float]]:
    """camera_to_world of a camera at ``position`` looking at the origin, rolled toward ``up``."""
    position = np.asarray(position, float)
    forward = -position / np.linalg.norm(position)
    x = np.cross(forward, up)
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(x, forward), -forward, position
    return m.tolist()


TILTED = _looking_at_origin(2.2 * np.array([-1.0, -1.2, 1.0]), [0.6, 0.0, 1.0])  # above, aside, rolled


def _capture(root, lights: bool, camera_to_world=CAMERA_TO_WORLD):
    root.mkdir(parents=True)
    (root / "images").mkdir()
    write_image(root / "images" / "0000.png", np.full((SIZE, SIZE, 3), 0.5))
    frame = {"name": "0000", "image": "images/0000.png",
             "camera": {"width": SIZE, "height": SIZE, "fx": 40.0, "fy": 40.0, "cx": SIZE / 2, "cy": SIZE / 2,
                        "camera_to_world": camera_to_world}}
    if lights:
        frame["lights"] = [{"type": "point", "position": [0.0, -3.0, 1.0], "intensity_w_per_sr": [FLASH] * 3}]
    (root / "capture.json").write_text(json.dumps({"format": "shape-from-tracing-capture", "frames": [frame]}))
    return root


def _patch_map(path, column: int, half: int = 4):
    """A black 32 x 16 map with a bright patch about the horizon at ``column`` (wrapping)."""
    pixels = np.zeros((16, 32, 3), np.float32)
    cols = [(column + k) % 32 for k in range(-half, half + 1)]
    pixels[8 - half:8 + half, cols] = 6.0 * 16 / (2 * half + 1) ** 2
    write_image(path, pixels, True)


def _run(root, mode: str, finished: bool):
    """A run folder as the backend leaves it under ``mode`` (estimate, rig, flash, captured, or
    env: captured with the map given on the command line)."""
    root.mkdir()
    if mode == "estimate":  # the light from world -y, the camera's side (u = 0.75)
        _patch_map(root / "environment.exr", 24)
    elif mode == "rig":  # the light from the rig's +x, toward the camera (u = 0.5)
        _patch_map(root / "environment.exr", 16)
    if finished:
        lighting = {"estimate": {"model": "environment map (estimated)", "file": "environment.exr", "frame": "world"},
                    "rig": {"model": "environment map (estimated)", "file": "environment.exr", "frame": "camera"},
                    "flash": {"model": "flash", "intensity": FLASH, "units": "W/sr"},
                    "captured": {"model": "captured", "emitters": 1}}[mode]
        (root / "report.json").write_text(json.dumps({"lighting": lighting, "material": {"light_factor": 1.0}}))
    else:
        argv = ["reconstruct", "capture", "--out", str(root)]
        if mode == "env":
            sky = write_image(root.parent / "sky.exr", np.ones((16, 32, 3), np.float32), True)
            argv += ["--env", str(sky), "--env-strength", "2", "--env-rotation", "10"]
        elif mode != "captured":
            argv += ["--lighting", mode]
        (root / "command.json").write_text(json.dumps({"argv": argv}))
        if mode == "flash":
            (root / "events.jsonl").write_text(json.dumps({"event": "lighting", "when": "fitted", "model": "flash",
                                                           "intensity": FLASH}) + "\n")
    return root


def _sphere_scene(context, addon, capture, tmp_path):
    assert bpy.ops.sft.import_cameras(filepath=str(capture / "capture.json")) == {"FINISHED"}
    mesh = icosphere(3)
    mesh.vertex_colors = np.full((mesh.n_vertices, 3), 0.5, np.float32)
    mesh.attributes = {"specular": np.full(mesh.n_vertices, 0.04, np.float32),
                       "roughness": np.full(mesh.n_vertices, 0.5, np.float32)}
    save_mesh(tmp_path / "sphere.ply", mesh)
    assert addon.jobs.show_snapshot(context, tmp_path / "sphere.ply")
    sft = context.scene.sft
    sft.preview_frame, sft.preview_samples, sft.preview_percentage = 0, 4, 100


@pytest.mark.parametrize("mode, finished, setting", [
    ("estimate", True, "ESTIMATE"), ("estimate", False, "ESTIMATE"), ("rig", True, "RIG"),
    ("rig", False, "RIG"), ("flash", True, "FLASH"), ("flash", False, "FLASH"), ("captured", True, "CAPTURED"),
    ("env", False, "CAPTURED")])
def test_relit_preview_renders_under_the_runs_own_lighting(context, addon, tmp_path, mode, finished, setting):
    capture = _capture(tmp_path / "capture", lights=mode == "captured")
    _sphere_scene(context, addon, capture, tmp_path)
    sft = context.scene.sft
    sft.run_dir = str(_run(tmp_path / "run", mode, finished))
    sft.lighting = "CAPTURED" if mode not in ("captured", "env") else "ESTIMATE"  # the run's record wins
    out = tmp_path / "preview.png"
    assert bpy.ops.sft.relit_preview(filepath=str(out)) == {"FINISHED"}
    render = np.asarray(Image.open(out).convert("RGB")).astype(np.float32)[:, :SIZE] / 255
    y, x = np.mgrid[:SIZE, :SIZE]
    centre = (y - SIZE / 2 + 0.5) ** 2 + (x - SIZE / 2 + 0.5) ** 2 < 5 ** 2  # the sphere's side facing the camera
    assert render[centre].mean() > 0.15, f"{mode}: the lit side is dark ({render[centre].mean():.3f})"
    corners = np.zeros_like(centre)
    corners[:3, :3] = corners[:3, -3:] = corners[-3:, :3] = corners[-3:, -3:] = True
    if mode in ("flash", "captured"):  # point lights only: no world, a black background
        assert render[corners].max() < 0.02
    if mode == "env":  # the map of the run's --env is the background, at its strength
        assert render[corners].min() > 0.9


def test_a_map_on_the_camera_turns_with_a_tilted_camera(context, addon, tmp_path):
    """A rig's map lights from the camera whatever its pose: a small patch at the rig's +x
    (toward the camera) makes the sphere brightest at the centre of its disc."""
    capture = _capture(tmp_path / "capture", lights=False, camera_to_world=TILTED)
    _sphere_scene(context, addon, capture, tmp_path)
    sft = context.scene.sft
    run = _run(tmp_path / "run", "rig", True)
    _patch_map(run / "environment.exr", 16, half=1)
    sft.run_dir, sft.preview_samples = str(run), 16
    assert bpy.ops.sft.relit_preview(filepath=str(tmp_path / "tilted.png")) == {"FINISHED"}
    render = np.asarray(Image.open(tmp_path / "tilted.png").convert("L")).astype(np.float32)[:, :SIZE] / 255
    y, x = np.mgrid[:SIZE, :SIZE] + 0.5
    weight = render ** 4  # the highlight
    centroid = np.array([(weight * y).sum(), (weight * x).sum()]) / weight.sum()
    assert render.max() > 0.3 and np.abs(centroid - SIZE / 2).max() < 1.2, (render.max(), centroid)


def test_relit_preview_says_when_the_runs_lighting_is_not_there_yet(context, addon, tmp_path):
    capture = _capture(tmp_path / "capture", lights=False)
    _sphere_scene(context, addon, capture, tmp_path)
    sft = context.scene.sft
    run = _run(tmp_path / "run", "flash", False)
    (run / "events.jsonl").unlink()  # the flash is not fitted yet
    sft.run_dir = str(run)
    expect_error(bpy.ops.sft.relit_preview, "the run has no fitted flash intensity yet")
    (run / "command.json").write_text(json.dumps({"argv": ["reconstruct", "c", "--out", str(run), "--lighting",
                                                           "estimate"]}))
    expect_error(bpy.ops.sft.relit_preview, "the run has no estimated environment map yet")
    sft.run_dir = ""  # nothing fitted, and the capture has no light of its own
    expect_error(bpy.ops.sft.relit_preview, "the capture has no lighting to render under")
    white = write_image(tmp_path / "white.exr", np.ones((16, 32, 3), np.float32), True)
    sft.lighting, sft.env_path = "CAPTURED", str(white)  # the imported map Reconstruct would use
    assert bpy.ops.sft.relit_preview(filepath=str(tmp_path / "imported.png")) == {"FINISHED"}
    sft.lighting, sft.env_path = "ESTIMATE", ""
    sft.preview_env = str(white)  # another HDR always renders
    assert bpy.ops.sft.relit_preview(filepath=str(tmp_path / "other.png")) == {"FINISHED"}
    for name in ("imported.png", "other.png"):
        assert np.asarray(Image.open(tmp_path / name).convert("RGB"))[:, :SIZE].mean() > 100, name
