"""Scene settings shown in the sidebar (``scene.sft``)."""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import capture_state
from .scene_cameras import show_labels
from .io.preset_file import PRESETS

QUALITY = (("auto", "Fit Budget", "The most accurate preset whose calibrated time fits the time budget, or the "
            "next one, cut at the budget, when the budget is twice that preset's time (Balanced when the "
            "budget is 0)"), *PRESETS)
MATERIALS = (
    ("FULL", "Full", "Spatially varying diffuse albedo, specular and roughness as mesh colors, fitted in stages "
     "(constants, diffuse, specular); exported with result.glb"),
    ("CONSTANT", "Constant", "One albedo, specular and roughness for the whole object: faster, for uniform objects"),
)
INITS = (
    ("AUTO", "Automatic", "Visual hull of the masks when every frame has one, else a sphere"),
    ("CARVE", "Visual Hull", "Carve the masks' visual hull (needs masks)"),
    ("SPHERE", "Sphere", "A sphere around the cameras' common focus"),
    ("POINTS", "SfM Points", "Screened Poisson surface of the solved cameras' sparse points"),
    ("OBJECT", "Blender Object", "Start from a mesh object of this scene (world coordinates)"),
)
EFFECTS = (
    ("AUTO", "Auto", "Measure which light-transport effects the scene calls for (bounces, shadow gradients, "
     "specular) and simulate only those"),
    ("ALL", "All", "Simulate every effect: slower, for scenes where the measurement may miss one"),
)
LIGHTING = (
    ("AUTO", "Auto", "Choose the lighting by a short probe after the first level: a map fixed to the world, one fixed to "
     "the camera, the two summed, or a flash at the camera, whichever renders held-out frames best (the panel "
     "shows the winner and its margin). The default while no map or lights are imported"),
    ("ESTIMATE", "Estimate", "Fit an environment map with the material (no HDR capture needed); the World shows "
     "it after the run. Albedo and light share one scale: the object's mean albedo is set to 0.5"),
    ("CAPTURED", "Captured HDR", "The imported environment map (Import Environment Map) or the capture's own lights"),
    ("RIG", "Estimate, on the camera", "Fit an environment map fixed to the camera instead of the world "
     "(lamps on the camera rig, as in DTU-like studios: the light turns with every view); the World is left "
     "as it is, the map stays in the run folder"),
    ("WORLD_RIG", "Estimate, world + camera", "Fit two maps together, one fixed to the world and one fixed to the "
     "camera, summed: a room's light plus lamps that turn with the camera (DTU-like studios). The World shows the "
     "world-fixed map after the run; the camera-fixed one stays in the run folder (environment_rig.exr)"),
    ("FLASH", "Camera flash", "A point light at every camera (a phone's flash, DTU-like captures), its intensity "
     "fitted with the material; the capture's own lights are replaced. The object's mean albedo is set to 0.5"),
)


def _is_mesh(_self, obj) -> bool:
    return obj.type == "MESH"


def _show_labels(self, context) -> None:
    """Show Labels: the frame cameras' backgrounds switch between the frames and their label overlays."""
    show_labels(context.scene, self.show_labels)


def _plan_stale(self, _context) -> None:
    """A setting the Plan line was measured with changed (the capture or a Reconstruct setting
    on Plan's command line): the line no longer holds, so it goes (Plan measures again)."""
    if self.plan_text:
        self.plan_text = ""


def _folder_changed(self, context) -> None:
    """The capture folder changed: the Plan line goes and the panels' view of the folder is read again."""
    _plan_stale(self, context)
    capture_state.on_setting_changed(self, context)


DEVICES = (
    ("AUTO", "Auto", "GPU when Cycles has one configured, else CPU"),
    ("CPU", "CPU", "Render on the CPU"),
    ("GPU", "GPU", "Render on the GPU configured in Cycles' preferences (falls back to CPU)"),
)


MASK_MODES = [
    ("AUTOMATIC", "Automatic", "The imported masks when there are any, else masks made from the solved cameras "
                               "(the points the cameras circle, segmented per frame and checked against each other)"),
    ("IMPORTED", "Imported", "Only the imported masks (Import Masks): Solve Cameras waits for them"),
]


class SFT_SceneSettings(bpy.types.PropertyGroup):
    capture_dir: StringProperty(
        name="Capture", subtype="DIR_PATH", default="",
        description="Capture folder: frames, masks and capture.json (set by the importers)",
        update=_folder_changed)
    run_dir: StringProperty(
        name="Run", subtype="DIR_PATH", default="",
        description="Run folder of the last reconstruction (snapshots, result, report)",
        update=capture_state.on_setting_changed)
    env_path: StringProperty(
        name="Environment", subtype="FILE_PATH", default="",
        description="HDR environment map of the capture (set by Import Environment Map)", update=_plan_stale)
    env_strength: FloatProperty(name="Strength", default=1.0, min=0.0, soft_max=10.0, update=_plan_stale)
    env_rotation: FloatProperty(name="Rotation Z", default=0.0, soft_min=-180.0, soft_max=180.0,
                                description="Environment rotation about Z, degrees", update=_plan_stale)
    map_calibrated: BoolProperty(
        name="Strength Calibrated", default=False,
        description="The map's strength is calibrated: keep it (no brightness factor is fitted), so the map sets "
                    "the albedo's scale. Off: a brightness factor is fitted with the albedo. A known median albedo "
                    "is set with Extra Arguments: --known-albedo R,G,B",
        update=_plan_stale)
    masks_mode: EnumProperty(name="Masks", items=MASK_MODES, default="AUTOMATIC",
                             description="Where Solve Cameras takes the object masks from")
    preset: EnumProperty(name="Quality", items=QUALITY, default="auto",
                         description="Reconstruction quality preset")
    plan_text: StringProperty(name="Plan", default="",
                              description="Each preset's predicted time on this capture (the Plan button)")
    time_budget: FloatProperty(name="Time Budget", default=30.0, min=0.0, soft_max=240.0, precision=0,
                               description="Minutes for the whole reconstruction: it stops then with the best "
                                           "mesh so far (0: until converged)", update=_plan_stale)
    track_accuracy: BoolProperty(
        name="Track Accuracy", default=False,
        description="Score views the run does not fit every 30 s and draw held-out PSNR against time "
                    "(RUN/accuracy_time.png; scoring time is not charged to the budget). A capture with "
                    "ground-truth held-out views scores those; otherwise every 8th view is held out of the fit, "
                    "which the reconstruction then lacks",
        update=_plan_stale)
    material: EnumProperty(name="Material", items=MATERIALS, default="FULL",
                           description="What the material model fits", update=_plan_stale)
    init: EnumProperty(name="Initialisation", items=INITS, default="AUTO", description="The starting mesh",
                       update=_plan_stale)
    init_object: PointerProperty(name="Object", type=bpy.types.Object, poll=_is_mesh,
                                 description="Mesh object to start from (empty: the active object)")
    effects: EnumProperty(name="Effects", items=EFFECTS, default="AUTO",
                          description="Light-transport effects simulated while optimising", update=_plan_stale)
    lighting: EnumProperty(name="Lighting", items=LIGHTING, default="AUTO",
                           description="Where the light comes from (Import Environment Map switches to Captured "
                                       "HDR, as does importing a capture with point lights)", update=_plan_stale)
    extra_args: StringProperty(
        name="Extra Arguments", default="",
        description="Further command-line options for 'python -m backend reconstruct' (they win over the "
                    "settings above)", update=_plan_stale)
    show_labels: BoolProperty(name="Show Labels", default=False, update=_show_labels,
                              description="The frame cameras show the material labels (Preview Material Labels) "
                                          "as a colour overlay instead of the frames")
    preview_frame: IntProperty(name="Frame", default=0, min=0,
                               description="Input frame whose camera the preview uses")
    preview_env: StringProperty(
        name="Other HDR", subtype="FILE_PATH", default="",
        description="Relight with this environment map instead of the run's own lighting")
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
