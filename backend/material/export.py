"""Baked textures and glTF 2.0 export of a reconstructed mesh with its material (numpy, json,
struct, Pillow; no bpy).

The atlas holds one square cell per face: the face occupies the right triangle (1, 1),
(c - 1, 1), (1, c - 1) of its c x c texel cell, so bilinear filtering never reads another
face's cell; texels outside the triangle hold the value at the nearest point of the
triangle. Every texel is evaluated exactly from the material (mesh colors or constants).
A face's cell follows its own mesh-color resolution r_f, c = 2 r_f + 3 (two texels per sample
interval), so the texture is as fine as the finest faces and its size grows with the faces'
count; cells are packed in rows, largest first, into a near-square atlas of at most
MAX_ATLAS texels a side (cells shrink together, to at least 3 texels, when they do not fit).

glTF mapping (metallic-roughness, metallic = 0): baseColorTexture = albedo (sRGB PNG),
metallicRoughnessTexture green = roughness (glTF alpha = roughness^2, as SurfaceBSDF),
KHR_materials_specular: specularTexture alpha = our specular, specularColorFactor = 25 so
that F0 = 0.04 x 25 x specular = specular at normal incidence. Positions are converted
from Blender's Z-up world to glTF's Y-up (Blender's importer converts back)."""

from __future__ import annotations

import io
import json
import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__, fsio
from ..capture.images import linear_to_srgb
from ..geometry.mesh import Mesh
from .model import MeshColorMaterial
from .transfer import closest_on_triangles

MAX_ATLAS = 8192
F0_DIELECTRIC = 0.04
Z_UP_TO_Y_UP = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])


@dataclass
class Atlas:
    uv: np.ndarray  # (F, 3, 2) glTF texture coordinates of each face corner (v down)
    albedo: np.ndarray  # (H, W, 3) linear
    specular: np.ndarray  # (H, W)
    roughness: np.ndarray  # (H, W)


def cell_sizes(material: MeshColorMaterial, cell: int | None = None) -> np.ndarray:
    """(F,) texel cell side of each face: ``cell``, or 2 r_f + 3 (at least 4) from its resolution."""
    if cell is not None:
        return np.full(material.n_faces, int(cell), np.int64)
    spatial = any(ch.kind == "colors" for ch in material.channels.values())
    r = material.resolutions if spatial else np.zeros(material.n_faces, np.int64)
    return np.maximum(4, 2 * r + 3).astype(np.int64)


def pack_cells(sizes: np.ndarray, limit: int = MAX_ATLAS) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Shelf packing of square cells: rows filled left to right with cells in decreasing size,
    in an atlas about as wide as it is high. Cells shrink by a common factor (to at least 3
    texels) until the atlas fits ``limit`` x ``limit``. Returns (sizes, origins (F, 2) x, y, W, H)."""
    sizes = np.asarray(sizes, np.int64)
    F = len(sizes)
    order = np.argsort(-sizes, kind="stable")
    scale = 1.0
    while True:
        c = np.maximum(3, np.floor(sizes * scale).astype(np.int64))
        width = int(max(c.max(initial=3), math.ceil(math.sqrt(float((c ** 2).sum())))))
        width = min(width, limit)
        origin = np.zeros((F, 2), np.int64)
        x = y = row = 0
        for f in order:
            if x + c[f] > width:
                x, y, row = 0, y + row, 0
            origin[f] = (x, y)
            x += c[f]
            row = max(row, c[f])
        height = y + row
        if height <= limit or c.max(initial=3) <= 3:
            return c, origin, width, max(height, 1)
        scale *= 0.97 * math.sqrt(limit / height)


def bake_atlas(mesh: Mesh, material: MeshColorMaterial, cell: int | None = None) -> Atlas:
    """Bake the material into per-face texture cells (see the module docstring)."""
    F = mesh.n_faces
    c, origin, W, H = pack_cells(cell_sizes(material, cell))
    albedo = np.zeros((H, W, 3), np.float32)
    spec = np.zeros((H, W), np.float32)
    rough = np.ones((H, W), np.float32)
    uv = np.zeros((F, 3, 2))
    flat = lambda p: np.c_[p, np.zeros(len(p))]  # noqa: E731
    for size in np.unique(c):
        faces = np.flatnonzero(c == size)
        corners = np.array([[1.0, 1.0], [size - 1.0, 1.0], [1.0, size - 1.0]])  # texel units inside a cell
        uv[faces] = (origin[faces, None, :] + corners[None]) / np.array([W, H])
        # barycentrics of every texel centre of a cell, clamped onto the triangle
        centres = np.stack(np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5, indexing="xy"), -1).reshape(-1, 2)
        n = len(centres)
        bary = closest_on_triangles(flat(centres), *(np.repeat(flat(corners[k:k + 1]), n, 0) for k in range(3)))
        vals = material.evaluate(np.repeat(faces, n), np.tile(bary[:, 1], len(faces)), np.tile(bary[:, 2], len(faces)))
        ty, tx = np.divmod(np.arange(n), size)
        rows_idx = (origin[faces, 1:2] + ty[None]).ravel()
        cols_idx = (origin[faces, 0:1] + tx[None]).ravel()
        albedo[rows_idx, cols_idx] = vals["albedo"]
        spec[rows_idx, cols_idx] = vals["specular"][:, 0]
        rough[rows_idx, cols_idx] = vals["roughness"][:, 0]
    return Atlas(uv, albedo, spec, rough)


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup at glTF coordinates (u right, v down), clamp to edge."""
    H, W = image.shape[:2]
    x, y = uv[:, 0] * W - 0.5, uv[:, 1] * H - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    if image.ndim == 3:
        fx, fy = fx[:, None], fy[:, None]
    px = lambda yy, xx: image[np.clip(yy, 0, H - 1), np.clip(xx, 0, W - 1)]  # noqa: E731
    return ((1 - fx) * (1 - fy) * px(y0, x0) + fx * (1 - fy) * px(y0, x0 + 1)
            + (1 - fx) * fy * px(y0 + 1, x0) + fx * fy * px(y0 + 1, x0 + 1))


def _png(array: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.round(np.clip(array, 0, 1) * 255).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def glb_bytes(mesh: Mesh, material: MeshColorMaterial, name: str = "reconstruction") -> bytes:
    """A binary glTF 2.0 file: one mesh, one material with baked textures."""
    atlas = bake_atlas(mesh, material)
    positions = (mesh.vertices[mesh.faces].reshape(-1, 3) @ Z_UP_TO_Y_UP.T).astype(np.float32)
    normals = (mesh.vertex_normals()[mesh.faces].reshape(-1, 3) @ Z_UP_TO_Y_UP.T).astype(np.float32)
    texcoords = atlas.uv.reshape(-1, 2).astype(np.float32)
    indices = np.arange(3 * mesh.n_faces, dtype=np.uint32)
    ones = np.ones_like(atlas.roughness)
    images = {"base_color": _png(linear_to_srgb(atlas.albedo)),
              "metallic_roughness": _png(np.stack([ones, atlas.roughness, 0 * ones], -1)),
              "specular": _png(np.stack([ones, ones, ones, atlas.specular], -1))}

    blob, views, accessors = bytearray(), [], []

    def add_view(data: bytes, target: int | None = None) -> int:
        while len(blob) % 4:
            blob.append(0)
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)}
        if target:
            view["target"] = target
        blob.extend(data)
        views.append(view)
        return len(views) - 1

    def add_accessor(array: np.ndarray, kind: str, component: int, target: int, bounds: bool = False) -> int:
        acc = {"bufferView": add_view(array.tobytes(), target), "componentType": component,
               "count": len(array), "type": kind}
        if bounds:
            acc["min"] = array.min(0).tolist()
            acc["max"] = array.max(0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    FLOAT, UINT, ARRAY, ELEMENTS = 5126, 5125, 34962, 34963
    attributes = {"POSITION": add_accessor(positions, "VEC3", FLOAT, ARRAY, bounds=True),
                  "NORMAL": add_accessor(normals, "VEC3", FLOAT, ARRAY),
                  "TEXCOORD_0": add_accessor(texcoords, "VEC2", FLOAT, ARRAY)}
    index_acc = add_accessor(indices, "SCALAR", UINT, ELEMENTS)
    image_ids = {k: i for i, k in enumerate(images)}
    gltf = {
        "asset": {"version": "2.0", "generator": f"shape-from-tracing {__version__}"},
        "extensionsUsed": ["KHR_materials_specular"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{"attributes": attributes, "indices": index_acc, "material": 0}]}],
        "materials": [{
            "name": f"{name}_material",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": image_ids["base_color"]},
                                     "metallicRoughnessTexture": {"index": image_ids["metallic_roughness"]},
                                     "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "extensions": {"KHR_materials_specular": {
                "specularFactor": 1.0, "specularTexture": {"index": image_ids["specular"]},
                "specularColorFactor": [1 / F0_DIELECTRIC] * 3}},
        }],
        "samplers": [{"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}],
        "textures": [{"sampler": 0, "source": i} for i in range(len(images))],
        "images": [{"name": k, "mimeType": "image/png", "bufferView": add_view(v)} for k, v in images.items()],
        "accessors": accessors,
        "bufferViews": views,
    }
    while len(blob) % 4:
        blob.append(0)
    gltf["buffers"] = [{"byteLength": len(blob)}]
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(text), b"JSON") + text
            + struct.pack("<I4s", len(blob), b"BIN\0") + bytes(blob))


def write_glb(path: str | Path, mesh: Mesh, material: MeshColorMaterial) -> None:
    """Write ``RUN/result.glb`` (atomically)."""
    fsio.write_bytes(path, glb_bytes(mesh, material, Path(path).stem))


def read_glb(path: str | Path) -> tuple[dict, bytes]:
    """The JSON and binary chunks of a .glb file (for checks and tests)."""
    data = Path(path).read_bytes()
    magic, version, total = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2 or total != len(data):
        raise ValueError(f"{path}: not a glTF 2.0 binary")
    n, kind = struct.unpack_from("<I4s", data, 12)
    gltf = json.loads(data[20:20 + n])
    m, _ = struct.unpack_from("<I4s", data, 20 + n)
    return gltf, data[28 + n:28 + n + m]
