"""Writing display meshes into the "Reconstruction" object with ``foreach_set``.

Colours are a point-domain colour attribute ``albedo`` (linear); ``specular`` and
``roughness`` are float point attributes; shading normals, when the snapshot has them, are
Blender's point-domain ``custom_normal`` attribute (free normals). The material reads the
attributes as the backend's BSDF: albedo / pi plus specular * D G / (4 cos cos) with GGX
alpha = roughness^2, which is a Diffuse BSDF added to a Glossy BSDF (GGX, no Fresnel) in
Cycles."""

import bpy
import numpy as np

from .io.ply import DisplayMesh

OBJECT_NAME = "Reconstruction"
SOURCE_PROPERTY = "sft_snapshot"  # the snapshot file an object shows (for Export glTF)
MATERIAL_NAME = "SfT Reconstruction"
COLOR_ATTRIBUTE = "albedo"
NORMAL_ATTRIBUTE = "custom_normal"
# a point-domain "custom_normal" attribute shades as custom normals from Blender 4.5 (free
# normals); the manifest allows 4.2, where Blender's own smooth normals are shown instead
FREE_NORMALS = bpy.app.version >= (4, 5, 0)


def reconstruction_material() -> bpy.types.Material:
    """Diffuse (albedo) + GGX glossy (grey specular, roughness) added: the backend's BSDF."""
    mat = bpy.data.materials.get(MATERIAL_NAME)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(MATERIAL_NAME)
    if bpy.app.version < (5, 0, 0):  # always on (and deprecated) from Blender 5
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    albedo = nodes.new("ShaderNodeVertexColor")
    albedo.layer_name = COLOR_ATTRIBUTE
    specular, roughness = nodes.new("ShaderNodeAttribute"), nodes.new("ShaderNodeAttribute")
    specular.attribute_name, roughness.attribute_name = "specular", "roughness"
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    glossy = nodes.new("ShaderNodeBsdfGlossy")
    glossy.distribution = "GGX"
    add = nodes.new("ShaderNodeAddShader")
    output = nodes.new("ShaderNodeOutputMaterial")
    links.new(albedo.outputs["Color"], diffuse.inputs["Color"])
    links.new(specular.outputs["Fac"], glossy.inputs["Color"])
    links.new(roughness.outputs["Fac"], glossy.inputs["Roughness"])
    links.new(diffuse.outputs["BSDF"], add.inputs[0])
    links.new(glossy.outputs["BSDF"], add.inputs[1])
    links.new(add.outputs["Shader"], output.inputs["Surface"])
    for node, xy in ((albedo, (-400, 200)), (specular, (-400, -50)), (roughness, (-400, -250)),
                     (diffuse, (-150, 150)), (glossy, (-150, -100)), (add, (100, 0)), (output, (300, 0))):
        node.location = xy
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
    corner_vert = mesh.attributes.get(".corner_vert")
    if len(mesh.loops) != dm.faces.size or corner_vert is None:
        return False
    corners = np.empty(len(mesh.loops), np.int32)
    corner_vert.data.foreach_get("value", corners)
    return bool(np.array_equal(corners, dm.faces.ravel()))


def _point_attribute(mesh, name: str, kind: str):
    attr = mesh.attributes.get(name)
    if attr is not None and (attr.data_type != kind or attr.domain != "POINT"):
        mesh.attributes.remove(attr)
        attr = None
    return attr or mesh.attributes.new(name, kind, "POINT")


def apply_display_mesh(obj: bpy.types.Object, dm: DisplayMesh) -> None:
    """Replace the object's geometry and material attributes; keeps its materials.

    Arrays go through the attribute API (``position``, ``.corner_vert``), which copies
    them in bulk; when the triangles are unchanged only values are written."""
    mesh = obj.data
    topology_changed = not _same_topology(mesh, dm)
    if topology_changed:
        mesh.clear_geometry()
        mesh.vertices.add(len(dm.vertices))
        mesh.loops.add(dm.faces.size)
        mesh.polygons.add(len(dm.faces))
        mesh.polygons.foreach_set("loop_start", np.arange(0, dm.faces.size, 3, dtype=np.int32))
        mesh.attributes[".corner_vert"].data.foreach_set("value", np.ascontiguousarray(dm.faces).ravel())
    mesh.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(dm.vertices, np.float32).ravel())
    if dm.colors is not None:
        color = _point_attribute(mesh, COLOR_ATTRIBUTE, "FLOAT_COLOR")
        rgba = np.ones((len(dm.colors), 4), np.float32)
        rgba[:, :3] = dm.colors
        color.data.foreach_set("color", rgba.ravel())
        mesh.color_attributes.active_color_name = COLOR_ATTRIBUTE
        mesh.color_attributes.render_color_index = mesh.color_attributes.find(COLOR_ATTRIBUTE)
    for name, values in dm.attributes.items():
        _point_attribute(mesh, name, "FLOAT").data.foreach_set("value", np.ascontiguousarray(values, np.float32))
    if dm.normals is not None and FREE_NORMALS:
        normals = _point_attribute(mesh, NORMAL_ATTRIBUTE, "FLOAT_VECTOR")
        normals.data.foreach_set("vector", np.ascontiguousarray(dm.normals, np.float32).ravel())
    elif mesh.attributes.get(NORMAL_ATTRIBUTE) is not None:  # Blender's own normals again
        mesh.attributes.remove(mesh.attributes[NORMAL_ATTRIBUTE])
    mesh.update(calc_edges=topology_changed)


def _read_point(mesh, name: str, kind: str, width: int) -> np.ndarray | None:
    """A point attribute's values, (V, width) float32, or None when it is missing or of
    another kind."""
    attr = mesh.attributes.get(name)
    if attr is None or attr.data_type != kind or attr.domain != "POINT":
        return None
    values = np.empty(len(mesh.vertices) * width, np.float32)
    attr.data.foreach_get({"FLOAT": "value", "FLOAT_COLOR": "color", "FLOAT_VECTOR": "vector"}[kind], values)
    return values.reshape(-1, width)


def shows(mesh: bpy.types.Mesh, dm: DisplayMesh) -> bool:
    """True when ``mesh`` holds exactly ``dm``: its triangles, positions, albedo and float
    attributes (what an edit in Blender would change)."""
    if not _same_topology(mesh, dm):
        return False
    pairs = [(_read_point(mesh, "position", "FLOAT_VECTOR", 3), dm.vertices)]
    if dm.colors is not None:
        rgba = _read_point(mesh, COLOR_ATTRIBUTE, "FLOAT_COLOR", 4)
        pairs.append((None if rgba is None else rgba[:, :3], dm.colors))
    for name, values in dm.attributes.items():
        pairs.append((_read_point(mesh, name, "FLOAT", 1), np.reshape(values, (-1, 1))))
    return all(have is not None and np.array_equal(have, np.asarray(want, np.float32)) for have, want in pairs)


def export_object_mesh(context, obj, path) -> int:
    """Write ``obj``'s evaluated mesh (modifiers applied, world coordinates, triangulated) as
    PLY for the backend's ``--init``; returns its face count."""
    from .io.ply import write_triangle_ply

    evaluated = obj.evaluated_get(context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    try:
        mesh.calc_loop_triangles()
        co = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        tris = np.empty(len(mesh.loop_triangles) * 3, np.int32)
        mesh.loop_triangles.foreach_get("vertices", tris)
        m = np.array(obj.matrix_world, dtype=np.float64)
        world = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
        write_triangle_ply(path, world, tris.reshape(-1, 3))
        return len(tris) // 3
    finally:
        evaluated.to_mesh_clear()
