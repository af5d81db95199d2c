"""Relit previews: Cycles renders the reconstruction from an input frame's camera under
the captured lighting (or another HDR), saved beside that frame as one image.

Rendering happens in a temporary scene, so the user's scene, world and render settings
stay as they were; only the image "SfT Relit Preview" is added or updated."""

import math
from pathlib import Path

import bpy
import numpy as np

from . import world
from .io.capture_file import CaptureInfo
from .io.files import png_bytes, write_atomic
from .images import read_rgba, to_display
from .scene_cameras import camera_object, configure_render

IMAGE_NAME = "SfT Relit Preview"


def cycles_device(context, choice: str) -> str:
    """'GPU' when asked for (or AUTO) and Cycles has a GPU configured, else 'CPU'."""
    if choice == "CPU":
        return "CPU"
    addon = context.preferences.addons.get("cycles")
    prefs = addon.preferences if addon else None
    if prefs is None or getattr(prefs, "compute_device_type", "NONE") == "NONE":
        return "CPU"
    prefs.refresh_devices()
    return "GPU" if any(d.use and d.type != "CPU" for d in prefs.devices) else "CPU"


def _point_light(light: dict) -> bpy.types.Object:
    """A capture point light: radiant intensity I (W/sr) is Blender power 4 pi I (W)."""
    intensity = np.asarray(light.get("intensity_w_per_sr", light.get("intensity", 1.0)), float)
    intensity = np.broadcast_to(intensity, 3)
    peak = float(intensity.max())
    data = bpy.data.lights.new(".sft_preview_light", "POINT")
    data.energy = 4.0 * math.pi * peak
    data.color = tuple(intensity / peak) if peak > 0 else (1.0, 1.0, 1.0)
    data.shadow_soft_size = 0.0
    obj = bpy.data.objects.new(".sft_preview_light", data)
    obj.location = tuple(light["position"])
    return obj


def render(context, obj: bpy.types.Object, info: CaptureInfo, frame_index: int, env: dict | None,
           use_lights: bool, samples: int, percentage: int, device: str, path: Path) -> None:
    """Render ``obj`` from frame ``frame_index``'s camera into the PNG ``path``."""
    frame = info.frames[frame_index]
    scene = bpy.data.scenes.new(".sft_preview")
    temporary = []
    try:
        scene.render.engine = "CYCLES"
        scene.cycles.samples = samples
        scene.cycles.use_denoising = False
        scene.cycles.device = cycles_device(context, device)
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        scene.render.film_transparent = False
        scene.render.image_settings.file_format = "PNG"
        scene.render.image_settings.color_mode = "RGB"
        scene.render.image_settings.color_depth = "8"
        scene.render.filepath = str(path)
        configure_render(scene, frame.camera, percentage)
        scene.collection.objects.link(obj)
        camera = camera_object(".sft_preview_camera", frame.camera)
        temporary.append(camera)
        scene.collection.objects.link(camera)
        scene.camera = camera
        if env:  # else no world: black
            scene.world = bpy.data.worlds.new(".sft_preview")
            image = world.load_environment_image(env["path"])
            world.set_environment(scene.world, image, env["strength"], env["rotation_z_deg"])
        for light in frame.lights if use_lights else []:
            temporary.append(_point_light(light))
            scene.collection.objects.link(temporary[-1])
        bpy.ops.render.render(write_still=True, scene=scene.name)
    finally:
        world_block = scene.world
        bpy.data.scenes.remove(scene)
        if world_block is not None:
            bpy.data.worlds.remove(world_block)
        for tmp in temporary:
            data = tmp.data
            bpy.data.objects.remove(tmp)
            (bpy.data.cameras if data.id_type == "CAMERA" else bpy.data.lights).remove(data)


def side_by_side(render_path: Path, frame_path: Path, out_path: Path) -> tuple[int, int]:
    """Write the render and the input frame (resized to it) side by side; returns its size."""
    rendered, _ = read_rgba(render_path)
    h, w = rendered.shape[:2]
    frame, linear = read_rgba(frame_path)
    rows = (np.arange(h) * frame.shape[0] // h)[:, None]
    cols = (np.arange(w) * frame.shape[1] // w)[None, :]
    frame = to_display(frame[rows, cols, :3], linear)
    both = np.concatenate([rendered[..., :3], frame], axis=1)
    write_atomic(out_path, png_bytes(np.rint(both * 255)))
    return 2 * w, h


def show(path: Path) -> bpy.types.Image:
    """Load (or reload) the preview as the image "SfT Relit Preview"."""
    image = bpy.data.images.get(IMAGE_NAME)
    if image is None:
        image = bpy.data.images.load(str(path))
        image.name = IMAGE_NAME
    else:
        image.filepath = str(path)
        image.reload()
    return image
