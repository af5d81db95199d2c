"""Panels Capture / Cameras / Reconstruct / Preview in the sidebar tab "Shape from Tracing".

Drawing reads no file: what the panels show of the capture and run folders comes from
:mod:`capture_state`'s cache, and the jobs' progress from their in-memory state. Each
panel's layout is a column of blocks (a job's progress, the settings, the actions), so
further settings slot in as blocks of their own."""

from pathlib import Path

import bpy

from .. import accuracy_curve, capture_state, jobs, scene_cameras, scene_mesh
from ..io import preset_file, progress

CATEGORY = "Shape from Tracing"


class _Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = CATEGORY


def _draw_job(layout, job: jobs.Job | None, cancel: str | None = None) -> bool:
    """Progress bar, stage, loss and ETA of a job; True while it runs. ``cancel``: the
    operator of its Cancel button (default: ``sft.cancel_job`` for the job's kind)."""
    if job is None:
        return False
    state = job.state
    col = layout.column(align=True)
    if state.active:
        col.progress(factor=state.fraction, type="BAR", text=f"{state.fraction:.0%}  {state.eta_text()}")
        col.label(text=state.headline())
        if state.plan_text():
            col.label(text=state.plan_text(), icon="TIME")
        if state.effects:
            col.label(text=f"Simulating: {state.effects}", icon="LIGHT")
            if state.shadow_samples:
                col.label(text=f"Cost: {state.shadow_samples}", icon="TIME")
        if state.lighting:
            col.label(text=f"Lighting: {state.lighting}", icon="WORLD")
        if state.smoothing:
            col.label(text=f"Smoothing: {state.smoothing}", icon="MOD_SMOOTH")
        if state.status == progress.STOPPING:
            col.label(text="Stopping after the current step...", icon="PAUSE")
        elif cancel:
            col.operator(cancel, icon="CANCEL")
        else:
            col.operator("sft.cancel_job", icon="CANCEL").kind = job.kind
        return True
    icon = {"done": "CHECKMARK", "cancelled": "CANCEL"}.get(state.status, "ERROR")
    col.label(text=state.headline(), icon=icon)
    return False


def _draw_accuracy(layout, job: jobs.Job | None) -> None:
    """Held-out PSNR against time (Track Accuracy): the backend's figure, updated in place."""
    if job is None or not job.state.accuracy:
        return
    box = layout.box().column(align=True)
    if accuracy_curve.shown():
        box.template_icon(icon_value=accuracy_curve.icon_id(), scale=9.0)
    box.label(text=job.state.accuracy_text(), icon="GRAPH")
    if job.state.next_level_text():
        box.label(text=job.state.next_level_text(), icon="TIME")


class SFT_PT_capture(_Panel, bpy.types.Panel):
    bl_idname = "SFT_PT_capture"
    bl_label = "Capture"

    def draw(self, context):
        sft = context.scene.sft
        layout = self.layout
        layout.prop(sft, "capture_dir")
        running = any(_draw_job(layout, jobs.ACTIVE.get(kind)) for kind in ("video", "masks"))
        col = layout.column(align=True)
        col.enabled = not running
        col.operator("sft.import_video", icon="FILE_MOVIE")
        col.operator("sft.import_masks", icon="MOD_MASK")
        col.operator("sft.import_environment", icon="WORLD")
        facts = capture_state.facts(context.scene)
        if facts.has_manifest:
            layout.label(text=f"{facts.frames} frames, {facts.masks} masks", icon="IMAGE_DATA")
        if sft.env_path:
            layout.label(text=f"{Path(sft.env_path).name}  x{sft.env_strength:g}  {sft.env_rotation:g}°",
                         icon="WORLD_DATA")


class SFT_PT_cameras(_Panel, bpy.types.Panel):
    bl_idname = "SFT_PT_cameras"
    bl_label = "Cameras"

    def draw(self, context):
        layout = self.layout
        running = _draw_job(layout, jobs.ACTIVE.get("solve"), cancel="sft.solve_cameras_cancel")
        col = layout.column(align=True)
        col.enabled = not running
        col.operator("sft.import_cameras", icon="CAMERA_DATA")
        col.prop(context.scene.sft, "masks_mode")
        col.operator("sft.solve_cameras", icon="TRACKING")
        collection = bpy.data.collections.get(scene_cameras.COLLECTION)
        if collection and collection.objects:
            layout.label(text=f"{len(collection.objects)} cameras", icon="OUTLINER_OB_CAMERA")


class SFT_PT_reconstruct(_Panel, bpy.types.Panel):
    bl_idname = "SFT_PT_reconstruct"
    bl_label = "Reconstruct"

    def draw(self, context):
        sft = context.scene.sft
        layout = self.layout
        job = jobs.ACTIVE.get("reconstruct")
        running = job is not None and job.running
        col = layout.column()
        col.enabled = not running
        col.prop(sft, "preset")
        facts = capture_state.facts(context.scene)
        calibration, measured_on = preset_file.kind_calibration(facts.calibration,
                                                                preset_file.kind_for(sft.lighting, sft.env_path))
        box = col.box().column(align=True)
        for key, label, _ in preset_file.PRESETS:
            box.label(text=f"{label}: {preset_file.describe(key, calibration)}",
                      icon="RADIOBUT_ON" if key == sft.preset else "RADIOBUT_OFF")
        box.label(text=measured_on, icon="INFO")
        plan = jobs.ACTIVE.get("plan")
        row = box.row(align=True)
        if plan is not None and plan.running:
            row.label(text="Measuring this capture's step costs and accuracy...", icon="TIME")
            row.operator("sft.plan_cancel", text="", icon="CANCEL")
        else:
            # one line per preset: the whole plan does not fit the sidebar's width
            parts = sft.plan_text.split(", ") if sft.plan_text else ["This capture: press Plan"]
            row.label(text=parts[0], icon="TIME")
            row.operator("sft.plan", text="Plan", icon="PREVIEW_RANGE")
            for part in parts[1:]:
                box.label(text=part, icon="BLANK1")
            if " dB)" in sft.plan_text:
                box.label(text="dB: predicted PSNR of views the run never fits", icon="INFO")
        col.prop(sft, "time_budget", text="Time Budget (min, 0 = until converged)")
        col.prop(sft, "track_accuracy")
        col.prop(sft, "material")
        col.prop(sft, "init")
        if sft.init == "OBJECT":
            col.prop(sft, "init_object")
        col.prop(sft, "effects")
        col.prop(sft, "lighting")
        if sft.lighting == "AUTO":
            col.label(text="Chosen by a short probe after the first level (world, camera, both summed, flash)",
                      icon="LIGHT_SUN")
        elif sft.lighting == "ESTIMATE":
            col.label(text="Lighting estimated with the material (mean albedo 0.5 sets the scale)", icon="WORLD_DATA")
        elif sft.lighting == "RIG":
            col.label(text="A map fixed to the camera, estimated with the material", icon="CAMERA_DATA")
        elif sft.lighting == "WORLD_RIG":
            col.label(text="A world-fixed map plus a camera-fixed one, estimated together", icon="WORLD_DATA")
        elif sft.lighting == "FLASH":
            col.label(text="A flash at each camera, intensity fitted (mean albedo 0.5 sets the scale)", icon="LIGHT_POINT")
        elif sft.env_path:
            col.label(text=f"Lighting: {Path(sft.env_path).name} x{sft.env_strength:g} {sft.env_rotation:g}°",
                      icon="WORLD_DATA")
            col.prop(sft, "map_calibrated", text="Strength calibrated (the map sets the albedo scale)")
        elif facts.point_lights:
            col.label(text=f"Lighting: the capture's point lights ({facts.point_lights})", icon="LIGHT_POINT")
        else:
            col.label(text="No lighting: Import Environment Map", icon="ERROR")
        if not running:
            row = layout.row(align=True)
            row.operator("sft.preview_labels", icon="COLOR")
            row.prop(sft, "show_labels", text="", icon="HIDE_OFF")
            row = layout.row(align=True)
            row.operator("sft.reconstruct", icon="PLAY")
            if facts.resumable:
                row.operator("sft.reconstruct_resume", icon="FILE_REFRESH")
        _draw_job(layout, job, cancel="sft.reconstruct_cancel")
        if job is not None and job.state.lighting_choice:  # --lighting auto's winner, its own row
            layout.label(text=job.state.lighting_choice, icon="LIGHT_SUN")
        _draw_accuracy(layout, job)
        if job is not None and job.state.refined_cameras:
            layout.label(text=job.state.refined_cameras, icon="OUTLINER_OB_CAMERA")
        if facts.exposure and not running:  # what the finished run refined: its per-frame gains
            layout.label(text=facts.exposure, icon="IMAGE_RGB_ALPHA")
        obj = bpy.data.objects.get(scene_mesh.OBJECT_NAME)
        if obj is not None and obj.type == "MESH" and obj.data.polygons:
            layout.label(text=f"{len(obj.data.polygons)} faces", icon="MESH_DATA")
            if not _draw_job(layout, jobs.ACTIVE.get("export")):
                layout.operator("sft.export_gltf", icon="EXPORT")


class SFT_PT_reconstruct_advanced(_Panel, bpy.types.Panel):
    bl_idname = "SFT_PT_reconstruct_advanced"
    bl_label = "Advanced"
    bl_parent_id = "SFT_PT_reconstruct"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        self.layout.prop(context.scene.sft, "extra_args")


class SFT_PT_preview(_Panel, bpy.types.Panel):
    bl_idname = "SFT_PT_preview"
    bl_label = "Preview"

    def draw(self, context):
        sft = context.scene.sft
        layout = self.layout
        layout.prop(sft, "preview_frame")
        layout.prop(sft, "preview_env")
        if sft.preview_env:
            row = layout.row(align=True)
            row.prop(sft, "preview_env_strength")
            row.prop(sft, "preview_env_rotation")
        row = layout.row(align=True)
        row.prop(sft, "preview_samples")
        row.prop(sft, "preview_percentage")
        layout.prop(sft, "device")
        if not _draw_job(layout, jobs.ACTIVE.get("preview")):
            layout.operator("sft.relit_preview", icon="RENDER_STILL")


CLASSES = (SFT_PT_capture, SFT_PT_cameras, SFT_PT_reconstruct, SFT_PT_reconstruct_advanced, SFT_PT_preview)
