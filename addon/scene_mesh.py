"""Writing display meshes into the "Reconstruction" object with ``foreach_set``.

Colours are a point-domain colour attribute ``albedo`` (linear); ``specular`` and
``roughness`` are float point attributes. The material reads them, so Cycles previews and
the glTF exporter see the reconstructed material (the backend's Lambert + GGX model:
GGX alpha = roughness^2 as in the Principled BSDF; the grey specular reflectance maps to
Specular IOR Level = specular / 0.08, whose normal-incidence reflectance is 0.08 * level)."""

import bpy
import numpy as np

from .ply import DisplayMesh

OBJECT_NAME = "Reconstruction"
MATERIAL_NAME = "SfT Reconstruction"
COLOR_ATTRIBUTE = "albedo"


def reconstruction_material() -> bpy.types.Material:
    mat = bpy.data.materials.get(MATERIAL_NAME)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(MATERIAL_NAME)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    color = nodes.new("ShaderNodeVertexColor")
    color.layer_name = COLOR_ATTRIBUTE
    color.location = (-500, 300)
    links.new(color.outputs["Color"], bsdf.inputs["Base Color"])
    rough = nodes.new("ShaderNodeAttribute")
    rough.attribute_name = "roughness"
    rough.location = (-500, 0)
    links.new(rough.outputs["Fac"], bsdf.inputs["Roughness"])
    spec = nodes.new("ShaderNodeAttribute")
    spec.attribute_name = "specular"
    spec.location = (-700, -250)
    scale = nodes.new("ShaderNodeMath")
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = 1.0 / 0.08
    scale.location = (-500, -250)
    links.new(spec.outputs["Fac"], scale.inputs[0])
    links.new(scale.outputs["Value"], bsdf.inputs["Specular IOR Level"])
    bsdf.inputs["IOR"].default_value = 1.5
    return mat


def reconstruction_object(context, name: str = OBJECT_NAME) -> bpy.types.Object:
    """The object that shows the reconstruction, created (empty) in the scene if needed."""
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "MESH":
        obj = bpy.data.objects.new(name, bpy.data.meshes.new(name))
    if context.scene not in obj.users_scene:
        context.scene.collection.objects.link(obj)
    if not obj.data.materials:
        obj.data.materials.append(reconstruction_material())
    return obj


def _same_topology(mesh: bpy.types.Mesh, dm: DisplayMesh) -> bool:
    if len(mesh.vertices) != len(dm.vertices) or len(mesh.polygons) != len(dm.faces):
        return False
    if len(mesh.loops) != dm.faces.size:
        return False
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    return bool(np.array_equal(corners, dm.faces.ravel()))


def _point_attribute(mesh, name: str, kind: str):
    attr = mesh.attributes.get(name)
    if attr is not None and (attr.data_type != kind or attr.domain != "POINT"):
        mesh.attributes.remove(attr)
        attr = None
    return attr or mesh.attributes.new(name, kind, "POINT")


def apply_display_mesh(obj: bpy.types.Object, dm: DisplayMesh) -> None:
    """Replace the object's geometry and material attributes; keeps its materials.

    When the triangles are unchanged only positions and attributes are written."""
    mesh = obj.data
    if not _same_topology(mesh, dm):
        mesh.clear_geometry()
        mesh.vertices.add(len(dm.vertices))
        mesh.loops.add(dm.faces.size)
        mesh.polygons.add(len(dm.faces))
        mesh.polygons.foreach_set("loop_start", np.arange(0, dm.faces.size, 3, dtype=np.int32))
        mesh.loops.foreach_set("vertex_index", dm.faces.ravel())
        topology_changed = True
    else:
        topology_changed = False
    mesh.vertices.foreach_set("co", np.ascontiguousarray(dm.vertices, np.float32).ravel())
    if dm.colors is not None:
        color = _point_attribute(mesh, COLOR_ATTRIBUTE, "FLOAT_COLOR")
        rgba = np.ones((len(dm.colors), 4), np.float32)
        rgba[:, :3] = dm.colors
        color.data.foreach_set("color", rgba.ravel())
        mesh.color_attributes.active_color_name = COLOR_ATTRIBUTE
        mesh.color_attributes.render_color_index = mesh.color_attributes.find(COLOR_ATTRIBUTE)
    for name, values in dm.attributes.items():
        _point_attribute(mesh, name, "FLOAT").data.foreach_set("value", np.ascontiguousarray(values, np.float32))
    mesh.update(calc_edges=topology_changed)
