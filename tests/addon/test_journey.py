"""The artist's journey, clicked with the defaults the panel shows, against the real backend:
Import Video -> Import Masks -> Import Environment Map -> Solve Cameras -> Reconstruct ->
Relit Preview -> Export glTF, on a small orbit video the project renders itself (Cycles,
an icosphere with a procedural texture, under the project's procedural sky); the headless
script's journey, without the HDR map (Lighting Estimate); the journey without masks (Masks
Automatic: made from the solved cameras). Only the
reconstruction's sizes shrink, through $SFT_RECONSTRUCT_SETTINGS (the backend's own
setting), never through Extra Arguments."""

from __future__ import annotations

import json
import re
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from PIL import Image

from .conftest import REPO

TINY = {"max_size": 48, "coarse_size": 32, "initial_faces": 400, "spp": 4, "iterations": 40, "max_levels": 2,
        "level_iterations": 20, "validation_views": 2}


@pytest.fixture(scope="module")
def orbit(tmp_path_factory) -> Path:
    """A 40-frame orbit video with index-paired masks and the HDR map it was lit by."""
    out = tmp_path_factory.mktemp("journey")
    from backend.capture.images import write_image
    from backend.synth.procedural import sky

    write_image(out / "sky.exr", sky(256))
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "render_orbit.py"), "--out", str(out / "orbit"),
                           "--env", str(out / "sky.exr"), "--frames", "40", "--size", "320x180", "--samples", "2",
                           "--denoise", "none"], capture_output=True, text=True, timeout=900, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


def _reports(capfd) -> str:
    out, err = capfd.readouterr()
    return out + err


def _glb_json(path: Path) -> dict:
    data = path.read_bytes()
    assert data[:4] == b"glTF"
    length, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON"
    return json.loads(data[20:20 + length])


def test_the_whole_journey_with_the_panels_defaults(context, extension, orbit, tmp_path, monkeypatch, capfd):
    monkeypatch.setenv("SFT_RECONSTRUCT_SETTINGS", json.dumps(TINY))
    video = shutil.copy(orbit / "orbit" / "orbit.mp4", tmp_path / "orbit.mp4")
    sft = context.scene.sft
    assert (sft.preset, sft.material, sft.init, sft.effects) == ("auto", "FULL", "AUTO", "AUTO")
    assert sft.time_budget == 30 and sft.extra_args == ""

    assert bpy.ops.sft.import_video(filepath=str(video)) == {"FINISHED"}
    capture = Path(sft.capture_dir)
    assert capture == tmp_path / "orbit_capture"
    frames = sorted((capture / "images").glob("*.png"))
    assert 30 <= len(frames) <= 40, "Target Count 40 keeps about 40 frames (blurred ones dropped)"
    assert re.search(r"\d+ frames in .*images", _reports(capfd))

    assert bpy.ops.sft.import_masks(filepath=str(orbit / "orbit" / "masks" / "0000.png")) == {"FINISHED"}
    assert len(list((capture / "masks").glob("*.png"))) == len(frames)
    assert bpy.ops.sft.import_environment(filepath=str(orbit / "sky.exr")) == {"FINISHED"}
    assert Path(sft.env_path).name == "sky.exr"
    assert "World lit by sky.exr" in _reports(capfd)

    assert bpy.ops.sft.solve_cameras() == {"FINISHED"}
    text = _reports(capfd)
    solved = Path(sft.capture_dir)
    assert solved == capture / "solved" and (solved / "capture.json").is_file()
    registered = int(re.search(r"solved: (\d+) cameras", text).group(1))
    assert registered >= 0.8 * len(frames), text[-2000:]
    doc = json.loads((solved / "capture.json").read_text())
    assert doc["environment"]["provenance"] == "estimated", "the HDR map was not aligned to the frames"
    assert sft.env_path and Path(sft.env_path).parent == solved, "the aligned map did not reach the scene"

    assert bpy.ops.sft.reconstruct() == {"FINISHED"}
    text = _reports(capfd)
    assert "reconstruction done" in text, text[-3000:]
    run = Path(sft.run_dir)
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    settings = next(e for e in events if e["event"] == "start")["settings"]
    assert settings["material"] == "staged" and settings["effects"] == "auto" and settings["max_size"] == 48
    assert settings["time_budget_s"] == 1800
    argv = json.loads((run / "command.json").read_text())["argv"]
    assert "--env" in argv and argv[argv.index("--env") + 1] == sft.env_path, "the HDR map never reached the backend"
    assert (run / "result.glb").is_file() and events[-1]["event"] == "done"
    obj = bpy.data.objects["Reconstruction"]
    assert len(obj.data.polygons) > 100 and obj.data.color_attributes.get("albedo") is not None

    assert bpy.ops.sft.relit_preview() == {"FINISHED"}
    previews = list((run / "preview").glob("*.png"))
    assert previews and "relit preview" in _reports(capfd)
    side = np.asarray(Image.open(next(p for p in previews if not p.stem.endswith("_render"))).convert("RGB"))
    assert side[:, : side.shape[1] // 2].std() > 3, "empty relit render"

    glb = tmp_path / "journey.glb"
    assert bpy.ops.sft.export_gltf(filepath=str(glb)) == {"FINISHED"}
    assert "the run's" in _reports(capfd)
    gltf = _glb_json(glb)
    assert "KHR_materials_specular" in gltf.get("extensionsUsed", []), "the export dropped the specular lobe"
    material = gltf["materials"][0]
    assert material["pbrMetallicRoughness"]["baseColorTexture"] is not None
    assert material["extensions"]["KHR_materials_specular"]["specularColorFactor"][0] > 0
    # the object shows the run's result unchanged: the export is the optimised mesh with its
    # exact textures (at resolution r > 1 the display mesh splits each face for its mesh colors),
    # named as the object
    result = _glb_json(run / "result.glb")
    faces = result["accessors"][result["meshes"][0]["primitives"][0]["indices"]]["count"] // 3
    assert faces == json.loads((run / "report.json").read_text())["result"]["faces"] <= len(obj.data.polygons)
    assert glb.read_bytes().endswith((run / "result.glb").read_bytes()[-1000:])  # the same binary chunk
    assert gltf["nodes"][0]["name"] == "Reconstruction" and "matrix" not in gltf["nodes"][0]
    blocked = tmp_path / "a_file"
    blocked.write_text("")  # a folder that is a file: one-line error, nothing written
    with pytest.raises(RuntimeError, match="cannot write the file"):
        bpy.ops.sft.export_gltf(filepath=str(blocked / "x.glb"))
    assert blocked.read_text() == ""
    # moved in the scene: the node carries the move, in glTF's Y-up axes
    obj.location = (0.5, 2.0, -1.0)
    bpy.context.view_layer.update()
    assert bpy.ops.sft.export_gltf(filepath=str(glb)) == {"FINISHED"}
    matrix = np.array(_glb_json(glb)["nodes"][0]["matrix"]).reshape(4, 4).T
    assert np.allclose(matrix[:3, 3], (0.5, -1.0, -2.0)) and np.allclose(matrix[:3, :3], np.eye(3))
    # edited in Blender: what the scene shows is baked instead
    obj.data.vertices[0].co.z += 0.01
    assert bpy.ops.sft.export_gltf(filepath=str(glb)) == {"FINISHED"}
    assert "baked textures" in _reports(capfd)
    edited = _glb_json(glb)
    assert edited["accessors"][edited["meshes"][0]["primitives"][0]["indices"]]["count"] // 3 == len(obj.data.polygons)


def _object_pixels(image: Path, mask: Path) -> np.ndarray:
    """The pixels (RGB in [0, 1]) of ``image`` inside ``mask`` (resized to it, nearest)."""
    rgb = np.asarray(Image.open(image).convert("RGB"), np.float64) / 255
    inside = np.asarray(Image.open(mask).convert("L").resize(rgb.shape[1::-1], Image.NEAREST)) > 127
    return rgb[inside]


def _glb_textures(path: Path) -> dict[str, np.ndarray]:
    """The texels the mesh of ``path`` uses (at its TEXCOORD_0, one per vertex, as rows of
    values in [0, 1]) in each image its material uses, by the slot that uses it (baseColor,
    metallicRoughness, specular): an atlas's unused texels are left out."""
    import io

    from backend.material.export import read_glb

    gltf, blob = read_glb(path)

    def view_bytes(index: int) -> bytes:
        view = gltf["bufferViews"][index]
        return blob[view.get("byteOffset", 0): view.get("byteOffset", 0) + view["byteLength"]]

    accessor = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]
    uv = np.frombuffer(view_bytes(accessor["bufferView"]), np.float32).reshape(accessor["count"], 2)
    material = gltf["materials"][0]
    slots = {"baseColor": material["pbrMetallicRoughness"].get("baseColorTexture"),
             "metallicRoughness": material["pbrMetallicRoughness"].get("metallicRoughnessTexture"),
             "specular": material.get("extensions", {}).get("KHR_materials_specular", {}).get("specularTexture")}
    out = {}
    for slot, ref in slots.items():
        if ref is None:
            continue
        image = gltf["images"][gltf["textures"][ref["index"]]["source"]]
        pixels = np.asarray(Image.open(io.BytesIO(view_bytes(image["bufferView"]))), np.float64) / 255
        h, w = pixels.shape[:2]
        cols = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
        rows = np.clip((uv[:, 1] * h).astype(int), 0, h - 1)
        out[slot] = pixels[rows, cols].reshape(len(uv), -1)
    return out


def test_the_headless_script_runs_the_journey_without_an_hdr_map(orbit, tmp_path):
    """``scripts/reconstruct.py VIDEO --masks M --out scene.blend --gltf out.glb`` (plain Python
    with the bpy module here; ``blender --background --python`` alike) with no HDR map: the
    panel's Lighting default, Auto, fits the lighting a held-out probe picks with the material,
    the relit preview renders under it (RUN/environment.exr, or the fitted flash), and the
    textures the run fitted reach result.glb. The HDR-lit journey is the panel's, above."""
    import os

    from backend.capture.load import load_capture

    video = shutil.copy(orbit / "orbit" / "orbit.mp4", tmp_path / "orbit.mp4")
    out = tmp_path / "scene.blend"
    env = dict(os.environ, SFT_RECONSTRUCT_SETTINGS=json.dumps(TINY))
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "reconstruct.py"), str(video), "--masks",
                           str(orbit / "orbit" / "masks" / "0000.png"), "--out", str(out),
                           "--gltf", str(tmp_path / "out.glb"), "--samples", "8"],
                          capture_output=True, text=True, timeout=1800, cwd=REPO, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = proc.stdout + proc.stderr
    assert out.is_file() and out.with_suffix(".preview.png").is_file()
    assert "KHR_materials_specular" in _glb_json(tmp_path / "out.glb").get("extensionsUsed", [])
    solved = tmp_path / "orbit_capture" / "solved"
    (run,) = list((solved / "runs").iterdir())
    argv = json.loads((run / "command.json").read_text())["argv"]
    assert argv[argv.index("--material") + 1] == "staged" and "--time-budget" in argv
    assert "--env" not in argv and argv[argv.index("--lighting") + 1] == "auto"
    report = json.loads((run / "report.json").read_text())
    winner = report["lighting_choice"]["winner"]  # the probe's pick among the fitted lightings
    assert winner in ("estimate", "rig", "world+rig", "flash"), report["lighting_choice"]
    if winner == "flash":
        assert "under the run's fitted flash" in printed, printed[-3000:]
    else:
        assert report["lighting"]["model"] == "environment map (estimated)", report["lighting"]
        assert (run / report["lighting"].get("file", "environment.exr")).is_file()
        # the preview rendered under the run's estimated map
        assert "under the run's estimated environment" in printed, printed[-3000:]

    # the object is lit in the preview
    frame = load_capture(solved).frames[0]
    rendered = _object_pixels(out.with_name(out.stem + ".preview_render.png"), frame.mask)
    captured = _object_pixels(frame.image, frame.mask)
    assert len(rendered) > 100, "the object is not in the preview's frame"
    lit = rendered.max(1) > 0.05
    print(f"relit object: mean {rendered.mean():.3f} (frame {captured.mean():.3f}), lit {lit.mean():.2f}")
    assert rendered.mean() > 0.3 * captured.mean() and lit.mean() > 0.8, "the relit preview is black"

    # result.glb carries the fitted textures, varying where the run fitted them per surface point
    channels = report["material"]["channels"]
    assert channels["albedo"] == "colors"
    textures = _glb_textures(run / "result.glb")
    assert textures["baseColor"][:, :3].std(0).max() > 0.02, "a constant base-colour texture"
    fitted = {"metallicRoughness": ("roughness", 1), "specular": ("specular", 3)}
    for slot, (name, band) in fitted.items():
        assert slot in textures
        if channels.get(name) == "colors":
            assert textures[slot][:, band].std() > 0.005, f"the fitted {name} is constant in result.glb"


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def test_the_journey_without_masks_makes_them_from_the_solved_cameras(context, extension, orbit, tmp_path,
                                                                      monkeypatch, capfd):
    """Masks = Automatic with none imported: Solve Cameras makes them from its SfM result (the
    object's points, GrabCut, the visual hull's check); they match the video's true masks, and
    the rest of the journey runs on them."""
    monkeypatch.setenv("SFT_RECONSTRUCT_SETTINGS", json.dumps(TINY))
    video = shutil.copy(orbit / "orbit" / "orbit.mp4", tmp_path / "orbit.mp4")
    sft = context.scene.sft
    assert sft.masks_mode == "AUTOMATIC"
    assert bpy.ops.sft.import_video(filepath=str(video)) == {"FINISHED"}
    capture = Path(sft.capture_dir)
    assert not list((capture / "masks").glob("*.png")), "no masks were imported"
    assert bpy.ops.sft.import_environment(filepath=str(orbit / "sky.exr")) == {"FINISHED"}

    assert bpy.ops.sft.solve_cameras() == {"FINISHED"}
    text = _reports(capfd)
    solved = Path(sft.capture_dir)
    doc = json.loads((solved / "capture.json").read_text())
    source = {f["name"]: f["source_frame"] for f in json.loads((capture / "frames.json").read_text())["frames"]}
    frames = [f for f in doc["frames"] if f.get("mask")]
    assert len(frames) >= 0.7 * len(source), text[-2000:]  # frames whose mask disagrees with the hull are dropped
    scores = []
    for frame in frames:
        made = np.asarray(Image.open(solved / frame["mask"]).convert("L")) > 127
        truth = Image.open(orbit / "orbit" / "masks" / f"{source[frame['name']]:04d}.png").convert("L")
        truth = np.asarray(truth.resize(made.shape[::-1], Image.NEAREST)) > 127
        scores.append(_iou(made, truth))
    assert np.mean(scores) >= 0.85 and min(scores) >= 0.6, scores

    assert bpy.ops.sft.reconstruct() == {"FINISHED"}
    assert "reconstruction done" in _reports(capfd)
    run = Path(sft.run_dir)
    assert (run / "result.glb").is_file()
    assert len(bpy.data.objects["Reconstruction"].data.polygons) > 100
    assert bpy.ops.sft.relit_preview() == {"FINISHED"}
    side = np.asarray(Image.open(next(p for p in (run / "preview").glob("*.png")
                                      if not p.stem.endswith("_render"))).convert("RGB"))
    assert side[:, : side.shape[1] // 2].std() > 3, "empty relit render"
    glb = tmp_path / "journey.glb"
    assert bpy.ops.sft.export_gltf(filepath=str(glb)) == {"FINISHED"}
    assert _glb_json(glb)["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] is not None
