"""A small reader for the backend's display meshes (bpy-free, numpy only).

Binary little-endian PLY with scalar vertex properties (``x y z``, optional ``red green
blue`` linear colours and ``nx ny nz`` shading normals, any further floats such as
``specular`` and ``roughness``) and triangles as counted index lists; see docs/protocol.md."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import AddonInputError, require

_TYPES = {"char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1", "short": "i2", "ushort": "u2",
          "int16": "i2", "uint16": "u2", "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
NORMALS = ("nx", "ny", "nz")


@dataclass
class DisplayMesh:
    vertices: np.ndarray  # (V, 3) float32
    faces: np.ndarray  # (F, 3) int32
    colors: np.ndarray | None = None  # (V, 3) float32 linear
    normals: np.ndarray | None = None  # (V, 3) float32 unit shading normals
    attributes: dict[str, np.ndarray] = field(default_factory=dict)  # per-vertex float32


def _header(f, path: Path) -> list[list[str]]:
    require(f.readline().strip() == b"ply", path, "not a PLY file", "write the mesh as PLY")
    lines = []
    while True:
        line = f.readline()
        require(bool(line), path, "PLY header has no end_header", "rewrite the file")
        words = line.decode("ascii", errors="replace").split()
        if words == ["end_header"]:
            return lines
        if words and words[0] not in ("comment", "obj_info"):
            lines.append(words)


def read_display_mesh(path: str | Path) -> DisplayMesh:
    """Read a binary little-endian triangle PLY."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            header = _header(f, path)
            data = f.read()
    except OSError as err:
        raise AddonInputError(path, f"cannot read mesh ({err.strerror})", "check the path") from err
    require(["format", "binary_little_endian", "1.0"] in header, path,
            "only binary little-endian PLY is read here", "write the mesh as binary PLY")
    elements = []  # (name, count, [(property, dtype) | ("list", count dtype, index dtype)])
    for words in header:
        if words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            require(bool(elements), path, "property before any element", "rewrite the file")
            if words[1] == "list":
                elements[-1][2].append(("list", _TYPES[words[2]], _TYPES[words[3]]))
            else:
                elements[-1][2].append((words[2], _TYPES[words[1]]))
    offset, vertex, faces = 0, None, None
    for name, count, props in elements:
        if any(p[0] == "list" for p in props):
            require(name == "face" and len(props) == 1, path, f"unsupported list element '{name}'",
                    "write only vertices and triangle faces")
            dtype = np.dtype([("n", "<" + props[0][1]), ("i", "<" + props[0][2], (3,))])
            require(len(data) >= offset + dtype.itemsize * count, path, "file is truncated",
                    "wait for the snapshot to be complete or rewrite it")
            arr = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            require(bool(np.all(arr["n"] == 3)), path, "faces are not all triangles",
                    "triangulate the mesh")
            faces = arr["i"].astype(np.int32)
        else:
            dtype = np.dtype([(p[0], "<" + p[1]) for p in props])
            require(len(data) >= offset + dtype.itemsize * count, path, "file is truncated",
                    "wait for the snapshot to be complete or rewrite it")
            arr = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            if name == "vertex":
                vertex = arr
        offset += dtype.itemsize * count
    require(vertex is not None and all(c in vertex.dtype.names for c in "xyz"), path,
            "PLY has no vertex positions", "write x, y, z per vertex")
    faces = np.zeros((0, 3), np.int32) if faces is None else faces
    require(faces.size == 0 or (faces.min() >= 0 and faces.max() < len(vertex)), path,
            "face indices point outside the vertex list", "rewrite the mesh")
    names = vertex.dtype.names
    mesh = DisplayMesh(np.stack([vertex[c] for c in "xyz"], -1).astype(np.float32), faces)
    if all(c in names for c in ("red", "green", "blue")):
        rgb = np.stack([vertex[c] for c in ("red", "green", "blue")], -1).astype(np.float32)
        mesh.colors = rgb / 255.0 if vertex["red"].dtype == np.uint8 else rgb
    if all(c in names for c in NORMALS):
        mesh.normals = np.stack([vertex[c] for c in NORMALS], -1).astype(np.float32)
    for n in names:
        if n not in ("x", "y", "z", "red", "green", "blue", "alpha", *NORMALS):
            mesh.attributes[n] = np.asarray(vertex[n], dtype=np.float32)
    return mesh


def write_triangle_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a binary little-endian PLY of triangles (the backend reads it as an --init mesh)."""
    vertices = np.ascontiguousarray(vertices, dtype="<f4").reshape(-1, 3)
    faces = np.asarray(faces, dtype="<i4").reshape(-1, 3)
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n").encode("ascii")
    rows = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rows["n"], rows["i"] = 3, faces
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(header + vertices.tobytes() + rows.tobytes())
    tmp.replace(path)
