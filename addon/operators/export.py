"""Export the reconstruction as glTF (binary) with baked textures.

The run's own result (the object shows it unchanged) is a file copy, done at once. Anything
baked or written from the scene runs in a child Blender (``addon/worker.py export``): Cycles
bakes hold the thread that starts them, and Blender's own bake job would bake the user's
scene, not a copy. The operator writes the object to a .blend in a scratch folder beside
the output, follows the worker as a job (progress and Cancel in the Reconstruct panel) and
moves the finished file into place, so a cancel leaves no file and the scene unchanged."""

import os
import shutil
import tempfile
from pathlib import Path

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper

from .. import export, jobs, scene_mesh
from ..io.errors import AddonInputError, require
from .common import abspath, fail, idle, poll_reconstruction, stopped
from .modal import JobModal


class SFT_OT_export_gltf(bpy.types.Operator, ExportHelper, JobModal):
    """Export the reconstruction as glTF: the run's optimised mesh with its exact textures while
    the object shows the run's result unchanged, else the object baked (or as vertex colours)"""

    bl_idname = "sft.export_gltf"
    bl_label = "Export glTF"

    job_kind = "export"

    filename_ext = ".glb"
    filter_glob: StringProperty(default="*.glb", options={"HIDDEN"})
    object_name: StringProperty(name="Object", default=scene_mesh.OBJECT_NAME)
    bake: BoolProperty(name="Bake Textures", default=True,
                       description="Bake albedo, roughness and specular into textures (else vertex colours)")
    texture_size: IntProperty(name="Texture Size", default=0, min=0, max=8192,
                              description="Baked texture width and height (0: automatic, and the run's own "
                                          "textures while the object shows its result unchanged)")

    @classmethod
    def poll(cls, context):
        return idle(cls, cls.job_kind) and poll_reconstruction(cls, context)

    def invoke(self, context, event):
        if context.scene.sft.run_dir and not self.filepath:
            self.filepath = str(abspath(context.scene.sft.run_dir) / "reconstruction.glb")
        return ExportHelper.invoke(self, context, event)

    def _object(self):
        obj = bpy.data.objects.get(self.object_name)
        require(obj is not None and obj.type == "MESH" and len(obj.data.polygons) > 0, None,
                f"no mesh object '{self.object_name}' to export", "run Reconstruct first")
        require(bool(self.filepath), None, "no output file", "choose a .glb file")
        return obj

    def execute(self, context):
        try:
            obj = self._object()
            result = export.run_result(obj) if self.bake and not self.texture_size else None
            if result is not None:  # a file copy: no job
                info = export.write_run_glb(result, abspath(self.filepath), obj.name, obj.matrix_world)
                return self._done(info)
        except AddonInputError as err:
            return fail(self, err)
        if bpy.app.background or context.window is None:
            return JobModal.execute(self, context)
        return self.start_modal(context)

    def start(self, context) -> jobs.Job:
        obj = self._object()
        self.out = abspath(self.filepath)
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            folder = Path(tempfile.mkdtemp(prefix=".sft-export-", dir=self.out.parent))
        except OSError as err:
            raise AddonInputError(self.out, f"cannot write the file ({err.strerror})",
                                  "choose another folder") from None
        try:
            bpy.data.libraries.write(str(folder / "object.blend"), {obj}, path_remap="ABSOLUTE", fake_user=True)
            args = ["export", str(folder / "object.blend"), obj.name, str(folder / "out.glb"),
                    "--size", str(self.texture_size), "--device", context.scene.sft.device]
            return jobs.WorkerJob(args + (["--bake"] if self.bake else []), self.job_kind, folder)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise

    def finish(self, context, job: jobs.WorkerJob):
        try:
            if job.state.status != "done":
                return stopped(self, job, "Export glTF")
            if not (job.folder / "out.glb").is_file():
                log = job.process.log_tail(3).replace("\n", " | ")
                return fail(self, AddonInputError(None, f"the export wrote no file ({log or 'no log'})",
                                                  "run Export glTF again, or without Bake Textures"))
            try:
                os.replace(job.folder / "out.glb", self.out)
            except OSError as err:
                return fail(self, AddonInputError(self.out, f"cannot write the file ({err.strerror})",
                                                  "choose another folder"))
            info = dict(job.state.done, path=str(self.out))
            return self._done(info)
        finally:
            job.cleanup()

    def _done(self, info: dict) -> set[str]:
        if info["source"] == "run":
            textures = f", the run's {info['texture_size']} px textures (albedo, roughness, specular)"
        else:
            textures = (f", {info['texture_size']} px baked textures (albedo, roughness, specular)"
                        if info["texture_size"] else ", vertex colours")
        self.report({"INFO"}, f"exported {info['faces']} faces{textures}: {info['path']}")
        return {"FINISHED"}


CLASSES = (SFT_OT_export_gltf,)
