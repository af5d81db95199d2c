"""Relit Preview: Cycles renders the reconstruction beside the matching input frame.

The render runs in a child Blender (``addon/worker.py render``), not in this one: a Cycles
render holds the thread that starts it, and Blender's own render job would take over the
user's render window and settings. The operator writes the temporary scene to a .blend in
a scratch folder, follows the worker as a job (progress and Cancel in the Preview panel)
and only once the render is complete writes the side-by-side image and shows it, so a
cancel leaves the scene and the preview folder as they were."""

import os
import shutil
import tempfile
from pathlib import Path

import bpy
from bpy.props import StringProperty

from .. import jobs, preview, scene_mesh, world
from ..io import capture_file
from ..io.errors import AddonInputError, require
from .common import abspath, capture_dir, fail, idle, poll_reconstruction, stopped
from .modal import JobModal


class SFT_OT_relit_preview(JobModal, bpy.types.Operator):
    """Render the reconstruction in Cycles from an input frame's camera, under the lighting its
    run fitted (the captured lights, the estimated map or the fitted flash) or another HDR,
    and show it beside that frame"""

    bl_idname = "sft.relit_preview"
    bl_label = "Relit Preview"
    bl_options = {"REGISTER", "UNDO"}

    job_kind = "preview"

    filepath: StringProperty(name="Output", subtype="FILE_PATH", default="",
                             description="PNG to write (empty: <run or capture>/preview/<frame>.png)")
    object_name: StringProperty(name="Object", default=scene_mesh.OBJECT_NAME)

    @classmethod
    def poll(cls, context):
        return idle(cls, cls.job_kind) and poll_reconstruction(cls, context, needs_capture=True)

    def start(self, context) -> jobs.Job:
        sft = context.scene.sft
        info = capture_file.read_capture(capture_dir(context))
        n = len(info.frames)
        require(sft.preview_frame < n, None, f"frame {sft.preview_frame} does not exist ({n} frames)",
                f"choose a frame from 0 to {n - 1}")
        frame = info.frames[sft.preview_frame]
        require(frame.image.is_file(), frame.image, "input frame not found", "restore the capture's images")
        obj = bpy.data.objects.get(self.object_name)
        require(obj is not None and obj.type == "MESH" and len(obj.data.polygons) > 0, None,
                f"no mesh object '{self.object_name}' to render", "run Reconstruct first")
        other = None
        if sft.preview_env:
            other = {"path": abspath(sft.preview_env), "strength": sft.preview_env_strength,
                     "rotation_z_deg": sft.preview_env_rotation}
        imported = None  # the map Reconstruct passes under Captured HDR
        if sft.lighting == "CAPTURED" and sft.env_path:
            imported = {"path": abspath(sft.env_path), "strength": sft.env_strength,
                        "rotation_z_deg": sft.env_rotation}
        run = abspath(sft.run_dir) if sft.run_dir else None
        info = capture_file.with_refined_cameras(info, run)  # --refine-cameras: the run's own cameras
        frame = info.frames[sft.preview_frame]
        self.lighting = preview.preview_lighting(info, run, sft.lighting, other, imported)
        if self.lighting.env:
            world.load_environment_image(self.lighting.env["path"])  # validate before rendering
        base = run if run is not None else info.root
        self.out = abspath(self.filepath) if self.filepath else base / "preview" / f"{frame.name}.png"
        self.frame_image = frame.image
        self.out.parent.mkdir(parents=True, exist_ok=True)
        folder = Path(tempfile.mkdtemp(prefix=".sft-preview-", dir=self.out.parent))
        try:
            name = preview.render(context, obj, info, sft.preview_frame, self.lighting, sft.preview_samples,
                                  sft.preview_percentage, sft.device, folder / "render.png", folder / "scene.blend")
            return jobs.WorkerJob(["render", str(folder / "scene.blend"), name], self.job_kind, folder)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise

    def finish(self, context, job: jobs.WorkerJob):
        try:
            if job.state.status != "done":
                return stopped(self, job, "Relit Preview")
            rendered = self.out.with_name(f"{self.out.stem}_render.png")
            try:
                require((job.folder / "render.png").is_file(), job.folder, "the render wrote no image",
                        "check the Cycles device in the Preview panel")
                os.replace(job.folder / "render.png", rendered)
                width, height = preview.side_by_side(rendered, self.frame_image, self.out)
            except AddonInputError as err:
                return fail(self, err)
            preview.show(self.out)
            self.report({"INFO"}, f"relit preview {width}x{height} {self.lighting.describe}: {self.out}")
            return {"FINISHED"}
        finally:
            job.cleanup()


CLASSES = (SFT_OT_relit_preview,)
