"""Capture cameras as Blender cameras (exact pinhole: lens, sensor width, shifts)."""

from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from .io.capture_file import BlenderCamera, CaptureInfo

COLLECTION = "SfT Cameras"


def configure_camera(data: bpy.types.Camera, cam: BlenderCamera) -> None:
    data.type = "PERSP"
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = cam.sensor_width
    data.lens = cam.lens
    data.shift_x, data.shift_y = cam.shift_x, cam.shift_y


def configure_render(scene: bpy.types.Scene, cam: BlenderCamera, percentage: int = 100) -> None:
    """Image size and pixel aspect of ``cam`` (non-square pixels when fx != fy)."""
    render = scene.render
    render.resolution_x, render.resolution_y = cam.width, cam.height
    render.resolution_percentage = percentage
    # pixel width : height = fy : fx, with the horizontal field of view kept
    aspect = cam.pixel_aspect
    render.pixel_aspect_x, render.pixel_aspect_y = (aspect, 1.0) if aspect >= 1 else (1.0, 1.0 / aspect)


def camera_object(name: str, cam: BlenderCamera) -> bpy.types.Object:
    data = bpy.data.cameras.new(name)
    configure_camera(data, cam)
    obj = bpy.data.objects.new(name, data)
    obj.matrix_world = Matrix(cam.matrix_world.tolist())
    return obj


def clear_collection(collection: bpy.types.Collection) -> None:
    for obj in list(collection.objects):
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            bpy.data.cameras.remove(data)


def create_cameras(context, info: CaptureInfo, show_frames: bool = True) -> list[bpy.types.Object]:
    """One camera per frame in the "SfT Cameras" collection (replacing earlier ones)."""
    scene = context.scene
    collection = bpy.data.collections.get(COLLECTION) or bpy.data.collections.new(COLLECTION)
    if collection.name not in scene.collection.children:
        scene.collection.children.link(collection)
    clear_collection(collection)
    centres = np.array([f.camera.matrix_world[:3, 3] for f in info.frames])
    spread = float(np.median(np.linalg.norm(centres - centres.mean(0), axis=1))) or 1.0
    objects = []
    for frame in info.frames:
        obj = camera_object(f"SfT {frame.name}", frame.camera)
        obj.data.display_size = 0.1 * spread
        obj["sft_frame"] = frame.name
        obj["sft_image"] = str(frame.image)
        if show_frames and frame.image.is_file():
            background = obj.data.background_images.new()
            background.image = bpy.data.images.load(str(frame.image), check_existing=True)
            obj.data.show_background_images = True
        collection.objects.link(obj)
        objects.append(obj)
    scene.camera = objects[0]
    configure_render(scene, info.frames[0].camera)
    return objects


def show_labels(scene, show: bool) -> int:
    """Each frame camera's background: its label overlay (``show``) or its frame. The count switched."""
    collection = bpy.data.collections.get(COLLECTION)
    switched = 0
    for obj in collection.objects if collection else ():
        path = obj.get("sft_labels" if show else "sft_image")
        if obj.type != "CAMERA" or not path or not Path(path).is_file():
            continue
        backgrounds = obj.data.background_images
        background = backgrounds[0] if len(backgrounds) else backgrounds.new()
        background.image = bpy.data.images.load(str(path), check_existing=True)
        obj.data.show_background_images = True
        switched += 1
    return switched
