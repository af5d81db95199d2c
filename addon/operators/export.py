"""Export the reconstruction as glTF (binary) with baked textures."""

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper

from .. import export, scene_mesh
from ..io.errors import AddonInputError, require
from .common import Busy, abspath, fail, poll_reconstruction


class SFT_OT_export_gltf(bpy.types.Operator, ExportHelper):
    """Export the reconstruction as glTF: the run's optimised mesh with its exact textures while
    the object shows the run's result unchanged, else the object baked (or as vertex colours)"""

    bl_idname = "sft.export_gltf"
    bl_label = "Export glTF"

    filename_ext = ".glb"
    filter_glob: StringProperty(default="*.glb", options={"HIDDEN"})
    object_name: StringProperty(name="Object", default=scene_mesh.OBJECT_NAME)
    bake: BoolProperty(name="Bake Textures", default=True,
                       description="Bake albedo and roughness into textures (else vertex colours)")
    texture_size: IntProperty(name="Texture Size", default=0, min=0, max=8192,
                              description="Baked texture width and height (0: automatic, and the run's own "
                                          "textures while the object shows its result unchanged)")

    @classmethod
    def poll(cls, context):
        return poll_reconstruction(cls, context)

    def invoke(self, context, event):
        if context.scene.sft.run_dir and not self.filepath:
            self.filepath = str(abspath(context.scene.sft.run_dir) / "reconstruction.glb")
        return ExportHelper.invoke(self, context, event)

    def execute(self, context):
        try:
            obj = bpy.data.objects.get(self.object_name)
            require(obj is not None and obj.type == "MESH" and len(obj.data.polygons) > 0, None,
                    f"no mesh object '{self.object_name}' to export", "run Reconstruct first")
            require(bool(self.filepath), None, "no output file", "choose a .glb file")
            with Busy(context, "Export glTF (baking)" if self.bake else "Export glTF"):
                info = export.export_gltf(context, obj, abspath(self.filepath), self.bake, self.texture_size,
                                          device=context.scene.sft.device)
        except AddonInputError as err:
            return fail(self, err)
        if info["source"] == "run":
            textures = f", the run's {info['texture_size']} px textures (albedo, roughness, specular)"
        else:
            textures = f", {info['texture_size']} px baked textures" if info["texture_size"] else ", vertex colours"
        self.report({"INFO"}, f"exported {info['faces']} faces{textures}: {info['path']}")
        return {"FINISHED"}


CLASSES = (SFT_OT_export_gltf,)
