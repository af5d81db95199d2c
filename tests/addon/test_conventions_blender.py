"""Conventions checked by rendering in Cycles: where an environment map's texels appear
(docs/capture-format.md's formula, with and without rotation), where a world point lands
for a capture camera (off-centre principal point, non-square pixels), and the backend's
own synthetic masks against Blender's render of the same mesh and cameras."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

from addon.io.capture_file import blender_camera
from addon.io.envmap import uv_to_direction
from backend.capture.model import Camera
from backend.synth.layout import look_at

from .media import centroid, render, spot_env


@pytest.mark.parametrize("rotation", [0.0, 40.0, -110.0])
def test_environment_spot_appears_where_formula_says(context, addon, tmp_path, rotation):
    u, v = 0.3, 0.35
    env = spot_env(tmp_path / "spot.exr", u, v, width=512, radius_px=2.0)
    bpy.ops.sft.import_environment(filepath=str(env), strength=1.0, rotation_z=rotation)
    d = uv_to_direction(u, v, rotation)  # the world direction the formula says shows the spot
    # a camera at the origin looking a little to the side of d, so the spot is off-centre
    target = d + 0.15 * np.cross(d, [0, 0, 1]) / np.linalg.norm(np.cross(d, [0, 0, 1]))
    cam = Camera(64, 64, 60.0, 60.0, 32.0, 32.0, look_at([0, 0, 0], target))
    scene = context.scene
    obj = addon.scene_cameras.camera_object("probe", blender_camera(cam.to_json()))
    scene.collection.objects.link(obj)
    scene.camera = obj
    addon.scene_cameras.configure_render(scene, blender_camera(cam.to_json()))
    img = render(scene, tmp_path / "probe.exr", samples=8)
    lum = img[..., :3].mean(-1)
    assert lum.max() > 1.0, "the spot is not in view"
    uv, depth = cam.project((50.0 * d)[None])
    assert depth[0] > 0
    x, y = centroid(np.where(lum > 0.2 * lum.max(), lum, 0.0))
    assert abs(x - uv[0, 0]) < 0.6 and abs(y - uv[0, 1]) < 0.6, ((x, y), uv)


@pytest.mark.parametrize("cx, cy, fy", [(32.0, 24.0, 50.0), (41.0, 17.5, 50.0), (20.0, 30.0, 58.0)])
def test_world_point_lands_on_projected_pixel(context, addon, tmp_path, cx, cy, fy):
    cam = Camera(64, 48, 50.0, fy, cx, cy, look_at([0.3, -3.0, 0.4], [0.0, 0.0, 0.2]))
    point = np.array([0.2, 0.1, 0.5])
    scene = context.scene
    scene.world = None  # black background
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.02, location=point.tolist(), segments=16, ring_count=8)
    ball = context.active_object
    mat = bpy.data.materials.new("glow")
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emit = nodes.new("ShaderNodeEmission")
    mat.node_tree.links.new(emit.outputs[0], nodes["Material Output"].inputs["Surface"])
    ball.data.materials.append(mat)
    bc = blender_camera(cam.to_json())
    obj = addon.scene_cameras.camera_object("probe", bc)
    scene.collection.objects.link(obj)
    scene.camera = obj
    addon.scene_cameras.configure_render(scene, bc)
    img = render(scene, tmp_path / "ball.exr", samples=16)
    assert img.shape[:2] == (48, 64)
    x, y = centroid(img[..., 0])
    uv, _ = cam.project(point[None])
    assert abs(x - uv[0, 0]) < 0.35 and abs(y - uv[0, 1]) < 0.35, ((x, y), uv)


def test_synthetic_masks_match_blender_silhouettes(context, addon, tiny_capture, tmp_path):
    """The backend (Mitsuba) made the capture; Blender renders the same mesh from the
    imported cameras. The silhouettes must agree."""
    assert bpy.ops.sft.import_cameras(filepath=str(tiny_capture / "capture.json")) == {"FINISHED"}
    gt = addon.io.ply.read_display_mesh(tiny_capture / "gt" / "mesh.ply")
    obj = addon.scene_mesh.reconstruction_object(context)
    addon.scene_mesh.apply_display_mesh(obj, gt)
    scene = context.scene
    info = addon.io.capture_file.read_capture(tiny_capture)
    from addon.images import read_rgba

    for i in (0, 3):
        frame = info.frames[i]
        scene.camera = bpy.data.objects[f"SfT {frame.name}"]
        addon.scene_cameras.configure_render(scene, frame.camera)
        alpha = render(scene, tmp_path / f"sil{i}.exr", samples=4, transparent=True)[..., 3] > 0.5
        mask = read_rgba(frame.mask)[0][..., 0] > 0.5
        iou = (alpha & mask).sum() / (alpha | mask).sum()
        assert iou > 0.95, (frame.name, iou)
