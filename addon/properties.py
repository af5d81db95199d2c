"""Scene settings shown in the sidebar (``scene.sft``)."""

import bpy
from bpy.props import EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from .presets import PRESETS

DEVICES = (
    ("AUTO", "Auto", "GPU when Cycles has one configured, else CPU"),
    ("CPU", "CPU", "Render on the CPU"),
    ("GPU", "GPU", "Render on the GPU configured in Cycles' preferences (falls back to CPU)"),
)


class SFT_SceneSettings(bpy.types.PropertyGroup):
    capture_dir: StringProperty(
        name="Capture", subtype="DIR_PATH", default="",
        description="Capture folder: frames, masks and capture.json (set by the importers)")
    run_dir: StringProperty(
        name="Run", subtype="DIR_PATH", default="",
        description="Run folder of the last reconstruction (snapshots, result, report)")
    env_path: StringProperty(
        name="Environment", subtype="FILE_PATH", default="",
        description="HDR environment map of the capture (set by Import Environment Map)")
    env_strength: FloatProperty(name="Strength", default=1.0, min=0.0, soft_max=10.0)
    env_rotation: FloatProperty(name="Rotation Z", default=0.0, soft_min=-180.0, soft_max=180.0,
                                description="Environment rotation about Z, degrees")
    preset: EnumProperty(name="Quality", items=PRESETS, default="balanced",
                         description="Reconstruction quality preset")
    extra_args: StringProperty(
        name="Extra Arguments", default="",
        description="Further command-line options for 'python -m backend reconstruct'")
    preview_frame: IntProperty(name="Frame", default=0, min=0,
                               description="Input frame whose camera the preview uses")
    preview_env: StringProperty(
        name="Other HDR", subtype="FILE_PATH", default="",
        description="Relight with this environment map instead of the captured lighting")
    preview_env_strength: FloatProperty(name="Strength", default=1.0, min=0.0, soft_max=10.0)
    preview_env_rotation: FloatProperty(name="Rotation Z", default=0.0, soft_min=-180.0, soft_max=180.0,
                                        description="Rotation of the other HDR about Z, degrees")
    preview_samples: IntProperty(name="Samples", default=32, min=1, soft_max=1024)
    preview_percentage: IntProperty(name="Resolution %", default=50, min=1, max=100, subtype="PERCENTAGE")
    device: EnumProperty(name="Device", items=DEVICES, default="AUTO",
                         description="Cycles device for previews and baking")


def register():
    bpy.utils.register_class(SFT_SceneSettings)
    bpy.types.Scene.sft = PointerProperty(type=SFT_SceneSettings)


def unregister():
    del bpy.types.Scene.sft
    bpy.utils.unregister_class(SFT_SceneSettings)
