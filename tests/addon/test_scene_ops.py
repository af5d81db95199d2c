"""Scene operators in Blender: cameras, live snapshot streaming (and its main-thread cost),
reconstruction jobs (done, crash, cancel), relit previews and glTF export."""

from __future__ import annotations

import io
import json
import math
import struct
import sys
import time

import bpy
import numpy as np
import pytest
from PIL import Image

from addon.io import interpreter
from backend import fsio
from backend.geometry.mesh import Mesh, save_mesh
from tests.conftest import run_cli

from .conftest import SCRIPTED_BACKEND, scene_state
from .media import write_image
from .test_capture_ops import expect_error


@pytest.fixture(scope="session")
def env_capture(tmp_path_factory):
    """The built-in object under the procedural sky, 4 views at 64 px (PNG frames)."""
    out = tmp_path_factory.mktemp("env") / "capture"
    run_cli("synth", "--out", out, "--views", 4, "--resolution", 64, "--spp", 32, "--lighting", "env",
            "--env", "sky", "--env-rotation", 35, "--format", "png", check=True)
    return out


@pytest.fixture(scope="session")
def lights_capture(tmp_path_factory):
    """The built-in object under two point lights per camera, 4 views at 64 px."""
    out = tmp_path_factory.mktemp("lights") / "capture"
    run_cli("synth", "--out", out, "--views", 4, "--resolution", 64, "--spp", 32, "--format", "png", check=True)
    return out


def _matrix(obj) -> np.ndarray:
    return np.array([list(row) for row in obj.matrix_world])


# --- cameras ---------------------------------------------------------------------------

def test_import_cameras_from_capture_json(context, env_capture):
    assert bpy.ops.sft.import_cameras(filepath=str(env_capture / "capture.json")) == {"FINISHED"}
    doc = json.loads((env_capture / "capture.json").read_text())
    cams = sorted(bpy.data.collections["SfT Cameras"].objects, key=lambda o: o.name)
    assert len(cams) == len(doc["frames"]) == 4
    for obj, frame in zip(cams, doc["frames"]):
        c = frame["camera"]
        np.testing.assert_allclose(_matrix(obj), c["camera_to_world"], atol=1e-6)
        assert obj.data.sensor_fit == "HORIZONTAL"
        assert obj.data.lens == pytest.approx(c["fx"] / c["width"] * obj.data.sensor_width, rel=1e-6)
        assert obj.data.shift_x == pytest.approx((c["width"] / 2 - c["cx"]) / c["width"], abs=1e-7)
        assert obj["sft_frame"] == frame["name"]
        assert obj.data.background_images[0].image.filepath == str(env_capture / frame["image"])
    scene = context.scene
    assert scene.camera == cams[0] and (scene.render.resolution_x, scene.render.resolution_y) == (64, 64)
    assert scene.sft.capture_dir == str(env_capture)
    mapping = next(n for n in scene.world.node_tree.nodes if n.type == "MAPPING")
    assert mapping.inputs["Rotation"].default_value[2] == pytest.approx(math.radians(35))
    # importing again replaces the cameras
    bpy.ops.sft.import_cameras(filepath=str(env_capture))
    assert len(bpy.data.collections["SfT Cameras"].objects) == 4 and len(bpy.data.cameras) == 4


def test_import_cameras_bad_input(context, env_capture, tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    doc = json.loads((env_capture / "capture.json").read_text())
    doc["frames"][1]["camera"]["camera_to_world"][0][3] = float("nan")
    (bad / "capture.json").write_text(json.dumps(doc).replace("NaN", "NaN"))
    expect_error(bpy.ops.sft.import_cameras, "frame 0001: camera pose contains NaN", filepath=str(bad / "capture.json"))
    (bad / "capture.json").write_text("{")
    expect_error(bpy.ops.sft.import_cameras, "invalid JSON", filepath=str(bad / "capture.json"))
    expect_error(bpy.ops.sft.import_cameras, "file not found", filepath=str(tmp_path / "none.json"))


def test_import_cameras_other_layouts_through_backend(context, env_capture, tmp_path):
    """A NeRF transforms.json (OpenGL camera-to-world, like ours) goes through the backend's
    importer; without that command the add-on says so."""
    doc = json.loads((env_capture / "capture.json").read_text())
    c0 = doc["frames"][0]["camera"]
    nerf = {"camera_angle_x": 2 * math.atan(c0["width"] / (2 * c0["fx"])),
            "frames": [{"file_path": str(env_capture / f["image"]).removesuffix(".png"),
                        "transform_matrix": f["camera"]["camera_to_world"]} for f in doc["frames"]]}
    (tmp_path / "transforms.json").write_text(json.dumps(nerf))
    if not interpreter.has_command("import"):
        expect_error(bpy.ops.sft.import_cameras, "no 'import' command", filepath=str(tmp_path / "transforms.json"))
        return
    assert bpy.ops.sft.import_cameras(filepath=str(tmp_path / "transforms.json")) == {"FINISHED"}
    cams = sorted(bpy.data.collections["SfT Cameras"].objects, key=lambda o: o.name)
    for obj, frame in zip(cams, doc["frames"]):
        np.testing.assert_allclose(_matrix(obj), frame["camera"]["camera_to_world"], atol=1e-5)


def test_solve_cameras_is_greyed_out_until_frames_and_masks_exist(context, addon, tmp_path):
    """poll() says what is missing (the button's tooltip); start() checks the files. poll()
    reads the cached view of the folder, refreshed here as the importers refresh it. With
    Masks = Imported it waits for imported masks; Automatic (the default) needs none."""
    expect_error(bpy.ops.sft.solve_cameras, "poll()", "import a video first (Import Video)")
    context.scene.sft.capture_dir = str(tmp_path)
    expect_error(bpy.ops.sft.solve_cameras, "import a video first (Import Video)")
    (tmp_path / "frames.json").write_text(json.dumps({"video": "v.mp4", "frames": [{"name": "0000"}]}))
    addon.capture_state.refresh(context.scene)
    assert context.scene.sft.masks_mode == "AUTOMATIC"
    expect_error(bpy.ops.sft.solve_cameras, "images: no frames", "import the video again")
    context.scene.sft.masks_mode = "IMPORTED"
    expect_error(bpy.ops.sft.solve_cameras, "import the object masks first (Import Masks), or set Masks to Automatic")
    (tmp_path / "masks").mkdir()
    (tmp_path / "masks" / "0000.png").write_bytes(b"")
    addon.capture_state.refresh(context.scene)
    expect_error(bpy.ops.sft.solve_cameras, "images: no frames", "import the video again")
    context.scene.sft.masks_mode = "AUTOMATIC"

def test_reconstruct_refuses_bad_input(context, addon, tmp_path):
    expect_error(bpy.ops.sft.reconstruct, "poll()", "import a video and solve its cameras, or import cameras")
    context.scene.sft.capture_dir = str(tmp_path)
    expect_error(bpy.ops.sft.reconstruct, "the capture has no cameras yet: Solve Cameras or Import Cameras")
    (tmp_path / "capture.json").write_text("{}")
    addon.capture_state.refresh(context.scene)  # as Import Cameras does once it wrote capture.json
    expect_error(bpy.ops.sft.reconstruct, "capture folder not found", capture_dir=str(tmp_path / "none"))
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "old.txt").write_text("x")
    expect_error(bpy.ops.sft.reconstruct, "run folder is not empty", run_dir=str(tmp_path / "run"))
    context.scene.sft.init = "OBJECT"
    expect_error(bpy.ops.sft.reconstruct, "no mesh object to start from")


# --- streaming -------------------------------------------------------------------------

def _grid_mesh(n: int, z: float = 0.0, seed: int = 0, normals: bool = True) -> Mesh:
    """An n x n vertex grid: 2 (n-1)^2 triangles, random colours, material values and
    (tilted, unit) shading normals."""
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n)), -1).reshape(-1, 2)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    attributes = {"specular": rng.random(n * n).astype(np.float32), "roughness": rng.random(n * n).astype(np.float32)}
    if normals:
        tilt = np.c_[0.3 * (g - 0.5), np.ones(len(g))]
        tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
        attributes.update(nx=tilt[:, 0].astype(np.float32), ny=tilt[:, 1].astype(np.float32),
                          nz=tilt[:, 2].astype(np.float32))
    return Mesh(np.c_[g, np.full(len(g), z)], faces, rng.random((n * n, 3)).astype(np.float32), attributes)


def _write_snapshot(run, step: int, mesh: Mesh) -> None:
    rel = f"snapshots/{step:06d}.ply"
    save_mesh(run / rel, mesh)
    fsio.write_json(run / "snapshot.json", {"mesh": rel, "iteration": step, "stage": "geometry", "loss": 0.1})


def _read_back(obj):
    me = obj.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    col = np.empty(len(me.vertices) * 4, np.float32)
    me.color_attributes["albedo"].data.foreach_get("color", col)
    rough = np.empty(len(me.vertices), np.float32)
    me.attributes["roughness"].data.foreach_get("value", rough)
    return co.reshape(-1, 3), col.reshape(-1, 4), rough


def test_100k_face_update_costs_under_50ms(context, addon, tmp_path):
    """Reading a 100k-face snapshot and writing it into the object, on the main thread."""
    run = tmp_path / "run"
    meshes = [_grid_mesh(225, z=0.01 * k, seed=k, normals=k != 3) for k in range(4)]
    assert meshes[0].n_faces > 100_000
    timings = {"rebuild": [], "same topology": []}
    for k, mesh in enumerate(meshes):
        if k == 2:  # a remesh: different triangles
            mesh.faces = mesh.faces[:, [0, 2, 1]]
        _write_snapshot(run, k, mesh)
        path = addon.jobs.latest_snapshot(run)
        t = time.perf_counter()
        assert addon.jobs.show_snapshot(context, path)
        timings["same topology" if k in (1, 3) else "rebuild"].append(time.perf_counter() - t)
        co, col, rough = _read_back(bpy.data.objects["Reconstruction"])
        np.testing.assert_allclose(co, mesh.vertices, atol=1e-6)
        np.testing.assert_array_equal(col[:, :3], mesh.vertex_colors)
        np.testing.assert_array_equal(rough, mesh.attributes["roughness"])
        corners = np.empty(mesh.n_faces * 3, np.int32)
        bpy.data.objects["Reconstruction"].data.loops.foreach_get("vertex_index", corners)
        np.testing.assert_array_equal(corners, mesh.faces.ravel())
        shown = np.empty(mesh.n_faces * 9, np.float32)  # what the viewport and Cycles shade with
        bpy.data.objects["Reconstruction"].data.corner_normals.foreach_get("vector", shown)
        normals = mesh.shading_normals
        if normals is None:  # Blender's own normals of the flat grid
            normals = np.tile([0, 0, 1.0], (mesh.n_vertices, 1))
        np.testing.assert_allclose(shown.reshape(-1, 3), normals[mesh.faces.ravel()], atol=1e-3)
    print({k: [f"{1000 * t:.1f} ms" for t in v] for k, v in timings.items()})
    assert max(timings["rebuild"]) < 0.05 and max(timings["same topology"]) < 0.05
    obj = bpy.data.objects["Reconstruction"]
    assert obj.data.materials[0].name == "SfT Reconstruction" and len(bpy.data.objects) == 1


def _scripted_job(addon, tmp_path, *options):
    run = tmp_path / "run"
    return addon.jobs.ReconstructJob(sys.executable, ["reconstruct", "capture", "--out", str(run), *options],
                                     run, "Reconstruction", root=SCRIPTED_BACKEND)


def test_job_streams_snapshots_into_the_scene(context, addon, tmp_path):
    job = _scripted_job(addon, tmp_path, "--steps", "6", "--delay", "0.1")
    shown = []
    while job.step(context):  # the update function the modal timer calls
        if job.applied and (not shown or shown[-1] != job.applied):
            shown.append(job.applied)
            shown_verts = _read_back(bpy.data.objects["Reconstruction"])[0]
            assert shown_verts.max() > 1.0  # the growing square
        time.sleep(0.05)
    assert job.state.status == "done" and job.state.done["metrics"] == {"f1": 0.5}
    assert len(shown) >= 3, "the mesh did not update while the backend ran"
    co, col, rough = _read_back(bpy.data.objects["Reconstruction"])
    np.testing.assert_allclose(co.max(0), [1.6, 1.6, 0.0])  # the last snapshot (step 6)
    np.testing.assert_allclose(col[0], [0.6, 0.5, 0.2, 1.0], atol=1e-6)
    assert max(job.apply_seconds) < 0.05


def test_a_snapshot_rewritten_under_its_name_is_shown_again(context, addon, tmp_path):
    """Material stages do not advance the iteration, so the backend rewrites one snapshot
    name; the scene must follow each rewrite, not only each new name."""
    import os

    job = _scripted_job(addon, tmp_path, "--steps", "3", "--delay", "0.02")
    job.run_blocking(context, interval=0.02)
    last = addon.jobs.latest_snapshot(tmp_path / "run")
    assert job.applied == str(last) and not job.apply_latest(context)  # shown and unchanged
    stat = last.stat()
    last.write_bytes(last.read_bytes())  # rewritten in place, as the backend's atomic replace does
    os.utime(last, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    assert job.apply_latest(context) and job.applied == str(last)
    assert not job.apply_latest(context)


def test_job_crash_reports_log_tail_and_keeps_snapshot(context, addon, tmp_path):
    job = _scripted_job(addon, tmp_path, "--mode", "crash", "--delay", "0.02")
    job.run_blocking(context, interval=0.02)
    assert job.state.status == "failed"
    assert "RuntimeError: scripted failure in the optimiser" in job.state.message
    assert _read_back(bpy.data.objects["Reconstruction"])[0].max() == pytest.approx(1.2)  # step 2


def test_job_cancel_keeps_last_snapshot(context, addon, tmp_path):
    job = _scripted_job(addon, tmp_path, "--steps", "1000", "--delay", "0.05")
    while job.applied is None:
        assert job.step(context)
        time.sleep(0.02)
    job.stop()
    assert job.state.status == "stopping"
    job.run_blocking(context, interval=0.02)
    assert job.state.status == "cancelled" and job.process.returncode == 130
    last = addon.jobs.latest_snapshot(tmp_path / "run")
    assert last.is_file() and job.applied == str(last)
    assert len(bpy.data.objects["Reconstruction"].data.polygons) == 2


# --- relit preview ---------------------------------------------------------------------

def _show_ground_truth(context, addon, capture):
    bpy.ops.sft.import_cameras(filepath=str(capture))
    addon.jobs.show_snapshot(context, capture / "gt" / "mesh.ply")


@pytest.mark.parametrize("which, tolerance", [("lights_capture", 0.02), ("env_capture", 0.04)])
def test_relit_preview_matches_backend_render(context, addon, which, tolerance, request, tmp_path):
    """Cycles renders the ground-truth mesh and material under the captured lighting; it
    must look like the frame the backend (Mitsuba) rendered: same cameras, lights, map, BSDF."""
    capture = request.getfixturevalue(which)
    _show_ground_truth(context, addon, capture)
    sft = context.scene.sft
    sft.preview_frame, sft.preview_samples, sft.preview_percentage = 1, 32, 100
    before = scene_state()
    out = tmp_path / "preview.png"
    assert bpy.ops.sft.relit_preview(filepath=str(out)) == {"FINISHED"}
    both = np.asarray(Image.open(out).convert("RGB")).astype(np.float32) / 255
    assert both.shape == (64, 128, 3)
    render, frame = both[:, :64], both[:, 64:]
    mask = np.asarray(Image.open(capture / "masks" / "0001.png").convert("L")) > 127
    assert render[mask].mean() > 0.1, "empty render"
    assert np.abs(render[mask].mean(0) - frame[mask].mean(0)).max() < tolerance
    assert np.abs(render - frame)[mask].mean() < 2 * tolerance
    after = scene_state()
    assert set(after["images"]) - set(before["images"]) <= {"SfT Relit Preview", "Render Result"}
    assert "SfT Relit Preview" in after["images"]
    assert {k: v for k, v in after.items() if k != "images"} == {k: v for k, v in before.items() if k != "images"}


def test_relit_preview_under_other_hdr(context, addon, env_capture, tmp_path):
    from .media import write_image

    _show_ground_truth(context, addon, env_capture)
    red = write_image(tmp_path / "red.exr", np.tile([[[1.0, 0.0, 0.0]]], (16, 32, 1)).astype(np.float32), True)
    sft = context.scene.sft
    sft.preview_env, sft.preview_samples, sft.preview_percentage = str(red), 8, 100
    bpy.ops.sft.relit_preview(filepath=str(tmp_path / "red.png"))
    render = np.asarray(Image.open(tmp_path / "red.png").convert("RGB"))[:, :64].astype(int)
    assert render[..., 0].mean() > 100 and render[..., 1:].max() <= 2  # lit by red light only


def test_cycles_device_choice(context, addon):
    prefs = context.preferences.addons["cycles"].preferences
    has_gpu = prefs.compute_device_type != "NONE" and any(d.type != "CPU" for d in prefs.get_devices_for_type(
        prefs.compute_device_type))
    assert addon.preview.cycles_device(context, "CPU") == "CPU"
    assert addon.preview.cycles_device(context, "AUTO") == ("GPU" if has_gpu else "CPU")


def test_relit_preview_bad_input(context, addon, env_capture, tmp_path):
    expect_error(bpy.ops.sft.relit_preview, "poll()", "no reconstruction yet: run Reconstruct first")
    bpy.ops.sft.import_cameras(filepath=str(env_capture))
    expect_error(bpy.ops.sft.relit_preview, "no reconstruction yet: run Reconstruct first")
    addon.jobs.show_snapshot(context, env_capture / "gt" / "mesh.ply")
    context.scene.sft.preview_frame = 9
    expect_error(bpy.ops.sft.relit_preview, "frame 9 does not exist (4 frames)")
    context.scene.sft.preview_frame = 0
    context.scene.sft.preview_env = str(tmp_path / "none.hdr")
    expect_error(bpy.ops.sft.relit_preview, "environment map not found")


# --- export ----------------------------------------------------------------------------

def _glb(path):
    data = path.read_bytes()
    assert data[:4] == b"glTF"
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + n])
    binary = data[20 + n + 8:]
    return doc, binary


def test_export_gltf_with_baked_textures(context, addon, lights_capture, tmp_path):
    _show_ground_truth(context, addon, lights_capture)
    before = scene_state()
    out = tmp_path / "recon.glb"
    assert bpy.ops.sft.export_gltf(filepath=str(out), texture_size=512) == {"FINISHED"}
    assert scene_state() == before and len(bpy.data.materials) == 1
    doc, binary = _glb(out)
    prim = doc["meshes"][0]["primitives"][0]
    assert "TEXCOORD_0" in prim["attributes"] and "COLOR_0" not in prim["attributes"]
    pbr = doc["materials"][0]["pbrMetallicRoughness"]
    assert "baseColorTexture" in pbr and "metallicRoughnessTexture" in pbr
    view = doc["bufferViews"][doc["images"][pbr["baseColorTexture"]["index"]]["bufferView"]]
    texture = np.asarray(Image.open(io.BytesIO(binary[view.get("byteOffset", 0):][:view["byteLength"]])).convert("RGB"))
    assert texture.shape == (512, 512, 3)
    # the texel at each face's atlas centre holds the face's mean albedo (sRGB-encoded)
    gt = addon.io.ply.read_display_mesh(lights_capture / "gt" / "mesh.ply")
    uv = addon.export.atlas_uvs(len(gt.faces), 512).reshape(-1, 3, 2).mean(1)
    faces = np.random.default_rng(0).choice(len(gt.faces), 200, replace=False)
    expected = gt.colors[gt.faces[faces]].mean(1)
    expected = np.where(expected <= 0.0031308, 12.92 * expected, 1.055 * expected ** (1 / 2.4) - 0.055)
    texel = texture[((1 - uv[faces, 1]) * 512).astype(int), (uv[faces, 0] * 512).astype(int)] / 255
    assert np.abs(texel - expected).mean() < 0.02


def test_export_gltf_vertex_colours_and_bad_input(context, addon, lights_capture, tmp_path):
    expect_error(bpy.ops.sft.export_gltf, "poll()", "no reconstruction yet", filepath=str(tmp_path / "x.glb"))
    _show_ground_truth(context, addon, lights_capture)
    out = tmp_path / "vc.glb"
    assert bpy.ops.sft.export_gltf(filepath=str(out), bake=False) == {"FINISHED"}
    doc, _ = _glb(out)
    prim = doc["meshes"][0]["primitives"][0]
    assert "COLOR_0" in prim["attributes"] and "TEXCOORD_0" not in prim["attributes"]
    assert doc["materials"][0]["pbrMetallicRoughness"]["roughnessFactor"] == pytest.approx(0.35, abs=1e-3)


def test_opening_another_file_stops_the_job_cleanly(context, addon, tmp_path):
    job = _scripted_job(addon, tmp_path, "--steps", "1000", "--delay", "0.05")
    while job.applied is None:
        job.step(context)
        time.sleep(0.02)
    bpy.ops.wm.read_homefile(use_empty=True)  # load_pre: the modal operator would end here
    assert (tmp_path / "run" / "STOP").exists() and job.state.status == "stopping"
    job.process.wait(timeout=30)  # what the drain timer does in the UI
    assert job.process.returncode == 130


def test_masks_and_material_labels_onto_imported_cameras(context, lights_capture, tmp_path):
    """Import Cameras, then Import Masks pairs one mask per frame (name order) and names them
    in capture.json; the backend reads them back (masks, and labels as material masks)."""
    import shutil

    from backend.capture.load import load_capture

    capture = tmp_path / "capture"
    shutil.copytree(lights_capture, capture)
    doc = json.loads((capture / "capture.json").read_text())
    for frame in doc["frames"]:  # an imported layout without masks
        frame.pop("mask", None)
    (capture / "capture.json").write_text(json.dumps(doc))
    shutil.rmtree(capture / "masks", ignore_errors=True)
    assert bpy.ops.sft.import_cameras(filepath=str(capture)) == {"FINISHED"}
    masks = tmp_path / "masks"
    masks.mkdir()
    for i in range(4):
        m = np.zeros((64, 64, 3), np.float32)
        m[10:50, 12 + i:52] = 1.0
        write_image(masks / f"m{i}.png", m)
    expect_error(bpy.ops.sft.import_masks, "3 masks for 4 frames", filepath=str(_three(tmp_path)))
    assert bpy.ops.sft.import_masks(filepath=str(masks / "m0.png")) == {"FINISHED"}
    assert bpy.ops.sft.import_masks(filepath=str(masks / "m0.png"), material=2) == {"FINISHED"}
    loaded = load_capture(capture)
    assert all(f.mask is not None and f.material_mask is not None for f in loaded.frames)
    from backend.capture.images import read_mask, read_rgba

    first = loaded.frames[0]
    assert read_mask(first.mask)[30, 30] == 1.0 and read_mask(first.mask)[2, 2] == 0.0
    labels = np.rint(read_rgba(first.material_mask)[0][..., 0] * 255)
    assert labels[30, 30] == 2 and labels[2, 2] == 0


def _three(tmp_path):
    folder = tmp_path / "three"
    folder.mkdir()
    for i in range(3):
        write_image(folder / f"{i}.png", np.ones((64, 64, 3), np.float32))
    return folder / "0.png"
