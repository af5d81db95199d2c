"""Relit Preview: Cycles renders the reconstruction beside the matching input frame."""

import bpy
from bpy.props import StringProperty

from .. import preview, scene_mesh, world
from ..io import capture_file
from ..io.errors import AddonInputError, require
from .common import Busy, abspath, capture_dir, fail, poll_reconstruction


class SFT_OT_relit_preview(bpy.types.Operator):
    """Render the reconstruction in Cycles from an input frame's camera, under the lighting its
    run fitted (the captured lights, the estimated map or the fitted flash) or another HDR,
    and show it beside that frame"""

    bl_idname = "sft.relit_preview"
    bl_label = "Relit Preview"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="Output", subtype="FILE_PATH", default="",
                             description="PNG to write (empty: <run or capture>/preview/<frame>.png)")
    object_name: StringProperty(name="Object", default=scene_mesh.OBJECT_NAME)

    @classmethod
    def poll(cls, context):
        return poll_reconstruction(cls, context, needs_capture=True)

    def execute(self, context):
        sft = context.scene.sft
        try:
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
            lighting = preview.preview_lighting(info, run, sft.lighting, other, imported)
            if lighting.env:
                world.load_environment_image(lighting.env["path"])  # validate before rendering
            base = run if run is not None else info.root
            out = abspath(self.filepath) if self.filepath else base / "preview" / f"{frame.name}.png"
            rendered = out.with_name(f"{out.stem}_render.png")
            out.parent.mkdir(parents=True, exist_ok=True)
            with Busy(context, f"Relit Preview ({sft.preview_samples} samples)") as busy:
                preview.render(context, obj, info, sft.preview_frame, lighting, sft.preview_samples,
                               sft.preview_percentage, sft.device, rendered)
                busy(0.9)
                width, height = preview.side_by_side(rendered, frame.image, out)
        except AddonInputError as err:
            return fail(self, err)
        preview.show(out)
        self.report({"INFO"}, f"relit preview {width}x{height} {lighting.describe}: {out}")
        return {"FINISHED"}


CLASSES = (SFT_OT_relit_preview,)
