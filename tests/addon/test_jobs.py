"""Nothing blocks and nothing goes stale: every long operator is a job (modal with a window,
progress on its panel, Cancel), cancelling leaves the capture and the scene as they were,
Esc cancels only over the sidebar, rotation-tagged videos come out upright, and a baked
export keeps the per-texel specular."""

from __future__ import annotations

import io
import json
import struct
import sys
import types

import bpy
import numpy as np
import pytest
from PIL import Image

from backend.geometry.mesh import save_mesh
from backend.geometry.primitives import icosphere

from .conftest import scene_state
from .media import pattern, write_video
from .test_relit_lighting import _capture

LONG_OPERATORS = ("import_video", "import_masks", "solve_cameras", "reconstruct", "plan", "relit_preview",
                  "export_gltf", "install_backend")


@pytest.fixture
def ended(addon):
    """The jobs that end, in order (the listener the panels' cache uses)."""
    out = []

    def listener(_context, job):
        out.append(job)

    addon.jobs.LISTENERS.append(listener)
    yield out
    addon.jobs.LISTENERS.remove(listener)
    for kind in ("video", "masks", "preview", "export"):
        addon.jobs.ACTIVE.pop(kind, None)


def test_each_long_operator_is_a_modal_job(context, addon):
    """With a window, invoke (or execute after the file browser) starts the job and returns
    RUNNING_MODAL; each has a job kind the panels draw progress and Cancel for."""
    modal = addon.operators.modal
    kinds = set()
    for name in LONG_OPERATORS:
        cls = getattr(bpy.types, f"SFT_OT_{name}")
        assert issubclass(cls, modal.JobModal), name
        assert cls.start is not modal.JobModal.start and cls.finish is not modal.JobModal.finish, name
        kinds.add(cls.job_kind)
    assert len(kinds) == len(LONG_OPERATORS), "one job kind each: a panel shows each one's progress"
    assert kinds <= set(addon.operators.common.RUNNING), "each says, while it runs, why others wait"


def test_import_video_is_a_job_with_progress_and_a_rotation_tagged_video_comes_out_upright(context, addon, ended,
                                                                                           tmp_path):
    """A portrait phone video (stored landscape, tagged 90 degrees clockwise): Import Video and
    the backend's capture-from-video reader both give upright frames."""
    frames = [pattern(i) for i in range(6)]
    video = write_video(tmp_path / "portrait.mp4", frames, rotate_cw=90)
    capture = tmp_path / "cap"
    assert bpy.ops.sft.import_video(filepath=str(video), capture_dir=str(capture), target_count=3,
                                    blur_threshold=0) == {"FINISHED"}
    (job,) = [j for j in ended if j.kind == "video"]
    assert job.state.status == "done" and job.state.fraction == 1.0
    manifest = json.loads((capture / "frames.json").read_text())
    assert (manifest["width"], manifest["height"]) == (48, 64)
    upright = [np.rot90(f, -1) for f in frames]  # turned clockwise
    for entry in manifest["frames"]:
        img = np.asarray(Image.open(capture / entry["image"]).convert("RGB")).astype(int)
        assert img.shape == (64, 48, 3)
        assert np.abs(img - upright[entry["source_frame"]]).mean() < 4
    from backend.video.frames import open_source

    source = open_source(video)
    assert (source.width, source.height) == (48, 64)
    for i, rgb in source.frames([0, 5]):
        assert np.abs(rgb.astype(int) - upright[i]).mean() < 4


def test_a_cancelled_import_leaves_the_capture_as_it_was(context, addon, tmp_path):
    """The import's task stopped midway: its temporary scene and folder go, frames.json and
    images/ are not written, and a capture folder it made is removed."""
    video = write_video(tmp_path / "phone.mp4", [pattern(i) for i in range(8)])
    capture = tmp_path / "cap"
    op = types.SimpleNamespace(every_nth=1, target_count=0, blur_threshold=0.0)  # the operator's settings
    cls = bpy.types.SFT_OT_import_video
    before = scene_state()
    scenes = len(bpy.data.scenes)
    job = addon.jobs.TaskJob(cls._extract(op, video, 8, 64, 48, capture), "video")
    try:
        assert job.step(context) and job.step(context)  # two frames decoded
        assert len(bpy.data.scenes) == scenes + 1 and 0 < job.state.fraction < 0.5
        assert bpy.ops.sft.cancel_job(kind="video") == {"FINISHED"}  # the panel's button
        assert not job.step(context)
    finally:
        addon.jobs.ACTIVE.pop("video", None)
    assert job.state.status == "cancelled"
    assert len(bpy.data.scenes) == scenes and scene_state() == before
    assert not capture.exists()


def test_esc_cancels_only_over_the_sidebar(addon):
    over = addon.operators.modal.over_sidebar
    region = lambda kind, x, w: types.SimpleNamespace(type=kind, x=x, y=0, width=w, height=500)  # noqa: E731
    screen = types.SimpleNamespace(areas=[
        types.SimpleNamespace(type="VIEW_3D", regions=[region("WINDOW", 0, 800), region("UI", 800, 200)]),
        types.SimpleNamespace(type="IMAGE_EDITOR", regions=[region("UI", 1000, 200)])])
    context = types.SimpleNamespace(window=types.SimpleNamespace(screen=screen))
    event = lambda x, y: types.SimpleNamespace(mouse_x=x, mouse_y=y)  # noqa: E731
    assert over(context, event(850, 100))
    assert not over(context, event(400, 100))  # the viewport itself
    assert not over(context, event(1100, 100))  # another editor's sidebar
    assert not over(types.SimpleNamespace(window=None), event(850, 100))


def _sphere(context, addon, tmp_path, specular):
    mesh = icosphere(3)
    mesh.vertex_colors = np.full((mesh.n_vertices, 3), 0.5, np.float32)
    mesh.attributes = {"specular": specular(mesh.vertices).astype(np.float32),
                       "roughness": np.full(mesh.n_vertices, 0.5, np.float32)}
    save_mesh(tmp_path / "sphere.ply", mesh)
    assert addon.jobs.show_snapshot(context, tmp_path / "sphere.ply")
    return mesh


def test_relit_preview_renders_in_a_worker_and_a_cancel_changes_nothing(context, addon, ended, tmp_path):
    capture = _capture(tmp_path / "capture", lights=True)
    assert bpy.ops.sft.import_cameras(filepath=str(capture / "capture.json")) == {"FINISHED"}
    _sphere(context, addon, tmp_path, lambda v: np.full(len(v), 0.04))
    sft = context.scene.sft
    sft.preview_samples, sft.preview_percentage = 2, 100
    out = tmp_path / "preview.png"
    assert bpy.ops.sft.relit_preview(filepath=str(out)) == {"FINISHED"}
    (job,) = [j for j in ended if j.kind == "preview"]
    assert job.state.status == "done" and job.process.argv[-3] == "render"
    assert out.is_file() and not job.folder.exists()
    # a cancel: the worker is stopped, its scratch folder goes, nothing is shown or written
    out.unlink()
    info = addon.io.capture_file.read_capture(capture)
    lighting = addon.preview.preview_lighting(info, None, "CAPTURED")
    folder = tmp_path / "scratch"
    folder.mkdir()
    name = addon.preview.render(context, bpy.data.objects["Reconstruction"], info, 0, lighting, 2, 100, "CPU",
                                folder / "render.png", folder / "scene.blend")
    before = scene_state()
    job = addon.jobs.WorkerJob(["render", str(folder / "scene.blend"), name], "preview", folder)
    job.stop()
    job.run_blocking(context, 0.02)
    assert job.state.status == "cancelled" and not folder.exists() and not out.exists()
    assert scene_state() == before


def _glb(path):
    data = path.read_bytes()
    n = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20:20 + n]), data[20 + n + 8:]


def _image(doc, binary, index) -> np.ndarray:
    view = doc["bufferViews"][doc["images"][doc["textures"][index]["source"]]["bufferView"]]
    data = binary[view.get("byteOffset", 0):][:view["byteLength"]]
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(np.float64) / 255


def test_an_edited_objects_bake_keeps_the_per_texel_specular(context, addon, ended, tmp_path):
    """Specular 0.3 on the upper half of a sphere, 0.02 below: the baked export's
    KHR_materials_specular gives F0 = specular face by face (texture times factors)."""
    mesh = _sphere(context, addon, tmp_path, lambda v: np.where(v[:, 2] > 0, 0.3, 0.02))
    before = scene_state()
    out = tmp_path / "edited.glb"
    assert bpy.ops.sft.export_gltf(filepath=str(out), texture_size=256) == {"FINISHED"}
    assert scene_state() == before
    (job,) = [j for j in ended if j.kind == "export"]
    assert job.state.status == "done" and not job.folder.exists()
    doc, binary = _glb(out)
    ext = doc["materials"][0]["extensions"]["KHR_materials_specular"]
    tint = _image(doc, binary, ext["specularColorTexture"]["index"])
    tint = np.where(tint <= 0.04045, tint / 12.92, ((tint + 0.055) / 1.055) ** 2.4)  # sRGB, as glTF reads it
    factor = np.asarray(ext.get("specularColorFactor", [1, 1, 1])) * ext.get("specularFactor", 1.0)
    uv = addon.export.atlas_uvs(len(mesh.faces), 256).reshape(-1, 3, 2).mean(1)
    faces = np.random.default_rng(0).choice(len(mesh.faces), 200, replace=False)
    expected = mesh.attributes["specular"][mesh.faces[faces]].mean(1)
    texel = tint[((1 - uv[faces, 1]) * 256).astype(int), (uv[faces, 0] * 256).astype(int)]
    f0 = addon.export.F0_DIELECTRIC * factor * texel
    assert np.abs(f0 - expected[:, None]).mean() < 0.01
    assert f0[expected > 0.2].mean() > 10 * f0[expected < 0.05].mean(), "one specular for the whole object"
