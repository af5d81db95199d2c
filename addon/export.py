"""glTF export of the reconstruction with baked textures.

When the object still shows a finished run's final snapshot unchanged, the export is the
run's own ``result.glb``: the optimised mesh (the display mesh is that mesh split for its
mesh colors, r² times the faces at resolution r) with textures evaluated exactly from the
material (albedo, roughness and specular), written again with the object's name and world
transform.

Otherwise (the object was edited, or the run stopped before its end) a temporary copy of
the object gets a triangle-atlas UV map (two triangles per square cell, kept apart by a
texel gap); Cycles bakes its albedo (the colour attribute through the material),
roughness and specular into images, and Blender's glTF exporter writes the copy with a
Principled material that reads those textures (or, without baking, the colour attribute
as vertex colours). The user's scene is left as it was.

Specular per texel: the texture holds s / s_max (sRGB-encoded, as glTF reads a specular
colour texture) into Specular Tint, and Specular IOR Level is 0.5 s_max / 0.04, so that
F0 = 0.04 (IOR 1.5) x 2 x level x tint = s in Cycles; the glTF exporter turns that level
into specularFactor (below 1) or folds it into specularColorFactor (above 1), which gives
F0 = s in KHR_materials_specular too. The add-on bakes in a child Blender
(``addon/worker.py export``), so Blender's UI never waits on Cycles."""

import json
import math
import struct
from pathlib import Path

import bpy
import numpy as np

from .io.errors import AddonInputError, require
from .io.files import write_atomic
from .io.ply import read_display_mesh
from .preview import cycles_device
from .scene_mesh import COLOR_ATTRIBUTE, SOURCE_PROPERTY, reconstruction_material, shows

# Blender's Z-up world to glTF's Y-up, as the backend writes result.glb
Z_UP_TO_Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, -1.0, 0, 0], [0, 0, 0, 1.0]])


def run_result(obj: bpy.types.Object) -> Path | None:
    """The run's ``result.glb`` when ``obj`` shows that run's final snapshot unchanged, else None."""
    source = obj.get(SOURCE_PROPERTY)
    if not source:
        return None
    snapshot = Path(source)
    run = snapshot.parent.parent  # RUN/snapshots/N.ply
    glb = run / "result.glb"
    try:
        doc = json.loads((run / "snapshot.json").read_text())
        final = doc.get("stage") == "done" and (run / doc["mesh"]).resolve() == snapshot.resolve()
        # the run writes result.glb after its final snapshot; an older one is another run's
        if not final or not glb.is_file() or glb.stat().st_mtime < snapshot.stat().st_mtime - 1:
            return None
        return glb if shows(obj.data, read_display_mesh(snapshot)) else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError, AddonInputError):
        return None


def _png_size(data: bytes) -> int:
    return struct.unpack_from(">I", data, 16)[0] if data[:8] == b"\x89PNG\r\n\x1a\n" else 0


def write_run_glb(source: Path, path: Path, name: str, matrix_world) -> dict:
    """Write the run's ``source`` .glb to ``path`` with its node and mesh named ``name`` and
    the node placed by ``matrix_world`` (Blender's, turned into glTF's Y-up); returns what
    was written. The file appears whole or not at all."""
    data = source.read_bytes()
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    n, kind = struct.unpack_from("<I4s", data, 12)
    require(magic == b"glTF" and version == 2 and total == len(data) and kind == b"JSON", source,
            "not a glTF 2.0 binary", "run Reconstruct again")
    gltf = json.loads(data[20:20 + n])
    node, mesh = gltf["nodes"][0], gltf["meshes"][0]
    node["name"] = mesh["name"] = name
    m = np.array(matrix_world, dtype=np.float64)
    if not np.allclose(m, np.eye(4)):
        node["matrix"] = (Z_UP_TO_Y_UP @ m @ Z_UP_TO_Y_UP.T).T.ravel().tolist()  # column-major
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    rest = data[20 + n:]
    out = struct.pack("<4sII", b"glTF", 2, 20 + len(text) + len(rest)) + struct.pack("<I4s", len(text), b"JSON") + text + rest
    try:
        write_atomic(path, out)
    except OSError as err:
        raise AddonInputError(path, f"cannot write the file ({err.strerror})", "choose another folder") from None
    binary = rest[8:]
    sizes = [_png_size(binary[v.get("byteOffset", 0):]) for v in (gltf["bufferViews"][i["bufferView"]]
                                                                 for i in gltf.get("images", []))]
    faces = gltf["accessors"][mesh["primitives"][0]["indices"]]["count"] // 3
    return {"path": str(path), "faces": faces, "texture_size": max(sizes, default=0), "source": "run"}


def atlas_uvs(n_faces: int, size: int) -> np.ndarray:
    """(n_faces * 3, 2) per-corner UVs: face 2k and 2k+1 share cell k, one on each side of
    the cell's diagonal, each inset so that bilinear lookups stay inside its own texels."""
    cells = max(1, math.ceil(math.sqrt(math.ceil(n_faces / 2))))
    texels = size / cells
    a = 0.75 / texels  # gap to the cell border
    b = a + 1.5 / (texels * math.sqrt(2))  # plus half of the gap across the diagonal
    lower = np.array([[a, a], [1 - b, a], [a, 1 - b]])
    upper = np.array([[1 - a, 1 - a], [b, 1 - a], [1 - a, b]])
    i = np.arange(n_faces)
    corner = np.where((i % 2 == 0)[:, None, None], lower, upper)  # (F, 3, 2)
    origin = np.stack([(i // 2) % cells, (i // 2) // cells], -1)[:, None, :]
    return ((origin + corner) / cells).reshape(-1, 2).astype(np.float32)


def texture_size(n_faces: int) -> int:
    """Power of two giving each atlas cell at least 8 texels, between 256 and 4096."""
    cells = math.ceil(math.sqrt(math.ceil(max(n_faces, 1) / 2)))
    return int(min(4096, max(256, 2 ** math.ceil(math.log2(8 * cells)))))


def _bake(context, scene, obj, image, kind: str) -> None:
    """Bake ``kind`` (DIFFUSE colour, ROUGHNESS, or EMIT) of ``obj``'s material into ``image``."""
    nodes = obj.active_material.node_tree.nodes
    target = nodes.get(".sft_bake") or nodes.new("ShaderNodeTexImage")
    target.name = ".sft_bake"
    target.image = image
    nodes.active = target
    override = dict(scene=scene, view_layer=scene.view_layers[0], active_object=obj, object=obj,
                    selected_objects=[obj], selected_editable_objects=[obj])
    with context.temp_override(**override):
        bpy.ops.object.bake(type=kind, pass_filter={"COLOR"} if kind == "DIFFUSE" else set(),
                            margin=2, margin_type="EXTEND", use_clear=True, target="IMAGE_TEXTURES")


F0_DIELECTRIC = 0.04  # glTF's F0 at specularFactor 1 and a white specular colour


def attribute_values(mesh, name: str) -> np.ndarray | None:
    values = mesh.attributes.get(name)
    if values is None or not len(values.data):
        return None
    buf = np.empty(len(values.data), np.float32)
    values.data.foreach_get("value", buf)
    return buf


def mean_attribute(mesh, name: str) -> float | None:
    values = attribute_values(mesh, name)
    return None if values is None else float(values.mean())


def _set_specular(bsdf, mesh, texture: bpy.types.Image | None = None, peak: float = 0.0) -> None:
    """KHR_materials_specular with F0 = specular at normal incidence: per texel from
    ``texture`` (specular / ``peak``, the module docstring), else the mean over the surface
    (Specular IOR Level 0.5, a specular colour of specular / 0.04)."""
    if texture is not None:
        tex = bsdf.id_data.nodes.new("ShaderNodeTexImage")
        tex.image = texture
        bsdf.id_data.links.new(tex.outputs["Color"], bsdf.inputs["Specular Tint"])
        bsdf.inputs["Specular IOR Level"].default_value = 0.5 * peak / F0_DIELECTRIC
        return
    specular = mean_attribute(mesh, "specular")
    if specular is None:
        return
    bsdf.inputs["Specular IOR Level"].default_value = 0.5
    tint = specular / F0_DIELECTRIC
    bsdf.inputs["Specular Tint"].default_value = (tint, tint, tint, 1.0)


def _specular_material(peak: float) -> bpy.types.Material:
    """Emission of specular / ``peak`` (the ``specular`` attribute), for baking it with EMIT."""
    mat = bpy.data.materials.new(".sft_bake_specular")
    if bpy.app.version < (5, 0, 0):  # always on (and deprecated) from Blender 5
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    attr, emission, out = (nodes.new(t) for t in ("ShaderNodeAttribute", "ShaderNodeEmission", "ShaderNodeOutputMaterial"))
    attr.attribute_name = "specular"
    links.new(attr.outputs["Fac"], emission.inputs["Color"])
    emission.inputs["Strength"].default_value = 1.0 / peak
    links.new(emission.outputs["Emission"], out.inputs["Surface"])
    return mat


def _export_material(mesh, color: bpy.types.Image | None, roughness: bpy.types.Image | None,
                     specular: bpy.types.Image | None = None, peak: float = 0.0) -> bpy.types.Material:
    """A Principled BSDF the glTF exporter understands: baked textures, or the colour
    attribute as base colour with the mean roughness; the specular lobe as KHR_materials_specular
    (per texel from ``specular``, the baked specular / ``peak``)."""
    mat = bpy.data.materials.new(".sft_export")
    if bpy.app.version < (5, 0, 0):  # always on (and deprecated) from Blender 5
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Metallic"].default_value = 0.0
    _set_specular(bsdf, mesh, specular, peak)
    if color is not None:
        tex = nodes.new("ShaderNodeTexImage")
        tex.image = color
        links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        rough = nodes.new("ShaderNodeTexImage")
        rough.image = roughness
        split = nodes.new("ShaderNodeSeparateColor")
        links.new(rough.outputs["Color"], split.inputs["Color"])
        links.new(split.outputs["Green"], bsdf.inputs["Roughness"])  # glTF reads roughness from G
    else:
        attr = nodes.new("ShaderNodeVertexColor")
        attr.layer_name = COLOR_ATTRIBUTE
        links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
        roughness_value = mean_attribute(mesh, "roughness")
        if roughness_value is not None:
            bsdf.inputs["Roughness"].default_value = roughness_value
    return mat


def _export_selected(context, obj: bpy.types.Object, path: Path) -> None:
    """Run the glTF exporter on ``obj`` alone in the current scene, then restore the
    scene's selection and active object."""
    view_layer = context.view_layer
    selected = [o for o in view_layer.objects if o.select_get()]
    active = view_layer.objects.active
    context.scene.collection.objects.link(obj)
    try:
        for o in selected:
            o.select_set(False)
        obj.select_set(True)
        view_layer.objects.active = obj
        bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB", use_selection=True)
    finally:
        context.scene.collection.objects.unlink(obj)
        for o in selected:
            o.select_set(True)
        view_layer.objects.active = active


def export_gltf(context, obj: bpy.types.Object, path: Path, bake: bool = True, size: int = 0,
                samples: int = 1, device: str = "AUTO", use_run: bool = True, progress=None) -> dict:
    """Write ``obj`` as binary glTF; returns what was written (``source``: ``run`` for the
    run's own result, ``scene`` for what was baked or written from the scene). ``use_run``:
    write the run's own result when the object shows it unchanged; ``progress(fraction,
    stage)`` is called before each bake and before writing."""
    progress = progress or (lambda fraction, stage: None)
    if use_run and bake and not size:
        result = run_result(obj)
        if result is not None:
            return write_run_glb(result, path, obj.name, obj.matrix_world)
    scene = bpy.data.scenes.new(".sft_export")  # for baking with Cycles
    mesh = obj.data.copy()
    copy = bpy.data.objects.new(".sft_export", mesh)
    copy.matrix_world = obj.matrix_world
    scene.collection.objects.link(copy)
    made_images, made_materials = [], []
    info = {"path": str(path), "faces": len(mesh.polygons), "texture_size": 0, "source": "scene"}
    name = obj.name
    try:
        color = rough = spec = None
        peak = 0.0
        if bake:
            size = size or texture_size(len(mesh.polygons))
            uv = mesh.uv_layers.new(name="UVMap")
            uv.data.foreach_set("uv", atlas_uvs(len(mesh.polygons), size).ravel())
            baking = reconstruction_material().copy()
            made_materials.append(baking)
            mesh.materials.clear()
            mesh.materials.append(baking)
            scene.render.engine = "CYCLES"
            scene.cycles.samples = samples
            scene.cycles.device = cycles_device(context, device)
            color = bpy.data.images.new(f"{name}_basecolor", size, size, alpha=False)
            rough = bpy.data.images.new(f"{name}_roughness", size, size, alpha=False)
            rough.colorspace_settings.name = "Non-Color"
            made_images += [color, rough]
            progress(0.05, "baking albedo")
            _bake(context, scene, copy, color, "DIFFUSE")
            progress(0.35, "baking roughness")
            _bake(context, scene, copy, rough, "ROUGHNESS")
            values = attribute_values(mesh, "specular")
            peak = float(values.max()) if values is not None else 0.0
            if peak > 0:
                progress(0.65, "baking specular")
                spec = bpy.data.images.new(f"{name}_specular", size, size, alpha=False)
                made_images.append(spec)
                made_materials.append(_specular_material(peak))
                mesh.materials[0] = made_materials[-1]
                _bake(context, scene, copy, spec, "EMIT")
                mesh.materials[0] = baking
            for attr in list(mesh.color_attributes):  # glTF multiplies COLOR_0 into the base colour
                mesh.color_attributes.remove(attr)
            info["texture_size"] = size
        progress(0.9, "writing glTF")
        made_materials.append(_export_material(mesh, color, rough, spec, peak))
        mesh.materials.clear()
        mesh.materials.append(made_materials[-1])
        path.parent.mkdir(parents=True, exist_ok=True)
        obj.name, copy.name = ".sft_exporting", name  # the glTF node keeps the object's name
        _export_selected(context, copy, path)
        return info
    finally:
        bpy.data.scenes.remove(scene)
        bpy.data.objects.remove(copy)
        obj.name = name
        bpy.data.meshes.remove(mesh)
        for mat in made_materials:
            bpy.data.materials.remove(mat)
        for image in made_images:
            bpy.data.images.remove(image)
