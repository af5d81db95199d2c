"""Baked texture atlas and result.glb: exact texels, valid glTF 2.0, imported by Blender's importer."""

import json
import subprocess
import sys
import textwrap

import numpy as np

from backend import variant

variant.choose()

from backend.capture.images import linear_to_srgb  # noqa: E402
from backend.material import export  # noqa: E402
from backend.synth import procedural  # noqa: E402
from tests.material.helpers import random_points  # noqa: E402
from tests.material.test_meshcolors import textured  # noqa: E402


def smooth_material(mesh, r=3):
    m = textured(mesh, r)
    pos = m.layout.sample_positions(mesh.vertices)
    m.set_values("albedo", procedural.albedo_pattern(pos, 3.0))
    m.set_values("specular", 0.2 + 0.1 * np.sin(4 * pos[:, 0]))
    m.set_values("roughness", 0.5 + 0.2 * np.cos(4 * pos[:, 1]))
    return m


def test_atlas_reproduces_the_material():
    mesh = procedural.blob(2)
    m = smooth_material(mesh)
    atlas = export.bake_atlas(mesh, m)
    assert atlas.uv.shape == (mesh.n_faces, 3, 2)
    assert atlas.uv.min() > 0 and atlas.uv.max() < 1
    rng = np.random.default_rng(0)
    face, b = random_points(mesh.n_faces, 4000, rng)
    uv = np.einsum("nk,nkd->nd", b, atlas.uv[face])
    truth = m.evaluate(face, b[:, 1], b[:, 2])
    for name, image in (("albedo", atlas.albedo), ("specular", atlas.specular), ("roughness", atlas.roughness)):
        got = export.sample_bilinear(image, uv).reshape(truth[name].shape)
        assert np.abs(got - truth[name]).mean() < 2e-3, name
        assert np.abs(got - truth[name]).max() < 0.03, name


def test_glb_is_valid_gltf(tmp_path):
    mesh = procedural.icosphere(1)
    m = smooth_material(mesh, 2)
    path = tmp_path / "result.glb"
    export.write_glb(path, mesh, m)
    gltf, blob = export.read_glb(path)
    assert gltf["asset"]["version"] == "2.0"
    prim = gltf["meshes"][0]["primitives"][0]
    pos = gltf["accessors"][prim["attributes"]["POSITION"]]
    assert pos["count"] == 3 * mesh.n_faces and pos["type"] == "VEC3"
    view = gltf["bufferViews"][pos["bufferView"]]
    xyz = np.frombuffer(blob, np.float32, 3 * pos["count"], view["byteOffset"]).reshape(-1, 3)
    assert np.allclose(xyz[:, [0, 2, 1]] * [1, -1, 1], mesh.vertices[mesh.faces].reshape(-1, 3), atol=1e-6)
    assert np.allclose(pos["min"], xyz.min(0)) and np.allclose(pos["max"], xyz.max(0))
    assert all(v["byteOffset"] % 4 == 0 and v["byteOffset"] + v["byteLength"] <= len(blob)
               for v in gltf["bufferViews"])
    material = gltf["materials"][0]
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert "KHR_materials_specular" in material["extensions"]
    assert [i["mimeType"] for i in gltf["images"]] == ["image/png"] * 3


BLENDER_CHECK = textwrap.dedent("""
    import bpy  # first: Blender's own glTF importer, in a fresh process
    import json
    import sys
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=sys.argv[-1])
    objects = [o for o in bpy.data.objects if o.type == "MESH"]
    mesh = objects[0].data
    nodes = objects[0].active_material.node_tree.nodes
    principled = [n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"][0]
    base = bpy.data.images["base_color"]
    w, h = base.size
    pixels = base.pixels[:]
    uv = mesh.uv_layers.active.data
    centre_colours = []  # base colour texel under each face's UV centroid, as Blender addresses it
    for poly in mesh.polygons[:40]:
        u = sum(uv[i].uv[0] for i in poly.loop_indices) / 3
        v = sum(uv[i].uv[1] for i in poly.loop_indices) / 3
        x, y = min(int(u * w), w - 1), min(int(v * h), h - 1)  # Blender: rows from the bottom
        centre_colours.append(pixels[4 * (y * w + x):4 * (y * w + x) + 3])
    print("RESULT", json.dumps({
        "centre_colours": centre_colours,
        "objects": len(objects), "faces": len(mesh.polygons), "uv_layers": len(mesh.uv_layers),
        "images": {i.name: list(i.size) for i in bpy.data.images},
        "linked": [k for k in ("Base Color", "Roughness") if principled.inputs[k].is_linked],
        "zmax": max(v.co.z for v in mesh.vertices)}))
""")


def test_blender_imports_the_glb(tmp_path):
    mesh = procedural.blob(1)
    m = smooth_material(mesh, 2)
    path = tmp_path / "result.glb"
    export.write_glb(path, mesh, m)
    script = tmp_path / "check.py"
    script.write_text(BLENDER_CHECK)
    proc = subprocess.run([sys.executable, str(script), str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(next(x for x in proc.stdout.splitlines() if x.startswith("RESULT"))[len("RESULT"):])
    assert out["objects"] == 1 and out["faces"] == mesh.n_faces and out["uv_layers"] == 1
    assert sorted(out["images"]) == ["base_color", "metallic_roughness", "specular"]
    assert all(min(size) > 1 for size in out["images"].values())
    assert out["linked"] == ["Base Color", "Roughness"]
    assert abs(out["zmax"] - mesh.vertices[:, 2].max()) < 1e-4  # Z up again in Blender
    # Blender reads the texture where the atlas put each face (UV orientation and sRGB agree)
    third = np.full(40, 1 / 3)
    expected = linear_to_srgb(m.evaluate(np.arange(40), third, third)["albedo"])
    assert np.abs(np.array(out["centre_colours"]) - expected).max() < 0.03


def test_atlas_of_mixed_resolutions_reproduces_the_material_and_follows_the_finest_faces():
    mesh = procedural.blob(2)
    m = smooth_material(mesh, 2)
    rng = np.random.default_rng(5)
    res = rng.integers(1, 4, mesh.n_faces)
    res[:10] = 12  # a few fine faces
    m.set_resolution(res)
    pos = m.layout.sample_positions(mesh.vertices)
    m.set_values("albedo", procedural.albedo_pattern(pos, 3.0))
    atlas = export.bake_atlas(mesh, m)
    sizes = export.cell_sizes(m)
    assert sizes.max() == 2 * 12 + 3 and sizes.min() == 2 * 1 + 3
    H, W = atlas.albedo.shape[:2]
    assert H * W >= int((sizes ** 2).sum()) and H * W < 2 * int((sizes ** 2).sum())
    # the fine faces' triangles span their large cells (u extent in texels)
    extent = (atlas.uv[:10, 1, 0] - atlas.uv[:10, 0, 0]) * W
    assert np.allclose(extent, 2 * 12 + 1)
    face, b = random_points(mesh.n_faces, 4000, rng)
    uv = np.einsum("nk,nkd->nd", b, atlas.uv[face])
    truth = m.evaluate(face, b[:, 1], b[:, 2])
    got = export.sample_bilinear(atlas.albedo, uv)
    assert np.abs(got - truth["albedo"]).mean() < 3e-3


def test_packing_shrinks_cells_to_fit_the_limit():
    sizes = np.full(500, 27)
    c, origin, W, H = export.pack_cells(sizes, limit=256)
    assert W <= 256 and H <= 256 and c.max() < 27
    assert np.all(origin[:, 0] + c <= W) and np.all(origin[:, 1] + c <= H)
