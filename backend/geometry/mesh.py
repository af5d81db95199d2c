"""A minimal triangle mesh (numpy arrays) with PLY/OBJ I/O.

Reading goes through pymeshlab (any format it knows); writing PLY is done here so that
per-vertex colours and attributes survive exactly and the write is atomic."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import fsio, ply
from ..errors import InputError


NORMAL_ATTRIBUTES = ("nx", "ny", "nz")  # optional shading normals among the attributes (PLY's names)


@dataclass
class Mesh:
    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64
    vertex_colors: np.ndarray | None = None  # (V, 3) float32 linear, optional
    attributes: dict[str, np.ndarray] = field(default_factory=dict)  # extra per-vertex arrays

    def __post_init__(self):
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def copy(self) -> "Mesh":
        return Mesh(self.vertices.copy(), self.faces.copy(),
                    None if self.vertex_colors is None else self.vertex_colors.copy(),
                    {k: v.copy() for k, v in self.attributes.items()})

    def face_normals(self, normalize: bool = True) -> np.ndarray:
        v = self.vertices[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        if normalize:
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        return n

    def face_areas(self) -> np.ndarray:
        return 0.5 * np.linalg.norm(self.face_normals(normalize=False), axis=1)

    def vertex_normals(self) -> np.ndarray:
        """Unit vertex normals, the face normals weighted by the corner angles (as Mitsuba
        computes the normals it shades with)."""
        n = np.zeros_like(self.vertices)
        fn = self.face_normals()
        corners = self.vertices[self.faces]
        for k in range(3):
            a = corners[:, (k + 1) % 3] - corners[:, k]
            b = corners[:, (k + 2) % 3] - corners[:, k]
            cos = (a * b).sum(1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30)
            np.add.at(n, self.faces[:, k], fn * np.arccos(np.clip(cos, -1.0, 1.0))[:, None])
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)

    @property
    def shading_normals(self) -> np.ndarray | None:
        """The (V, 3) normals carried as attributes nx, ny, nz, or None."""
        if not all(k in self.attributes for k in NORMAL_ATTRIBUTES):
            return None
        return np.stack([self.attributes[k] for k in NORMAL_ATTRIBUTES], -1)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(0), self.vertices.max(0)

    def transformed(self, matrix: np.ndarray) -> "Mesh":
        out = self.copy()
        out.vertices = self.vertices @ matrix[:3, :3].T + matrix[:3, 3]
        normals = self.shading_normals
        if normals is not None:
            normals = normals @ np.linalg.inv(matrix[:3, :3])  # the inverse transpose carries normals
            normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
            out.attributes.update(zip(NORMAL_ATTRIBUTES, normals.T.astype(np.float32)))
        return out


def load_mesh(path: str | Path) -> Mesh:
    """Load OBJ/PLY/STL/OFF... as one triangle mesh (vertices merged by pymeshlab's loader)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "mesh file not found", "check the path")
    if path.suffix.lower() == ".ply":
        mesh = _read_ply(path)
        if mesh is not None:
            return mesh
    import pymeshlab

    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except Exception as err:
        raise InputError(path, f"cannot read mesh ({err})".replace("\n", " "),
                         "export it as OBJ or PLY") from err
    m = ms.current_mesh()
    if m.face_number() == 0:
        raise InputError(path, "mesh has no faces", "export a triangle mesh, not a point cloud")
    mesh = Mesh(m.vertex_matrix(), m.face_matrix())
    return mesh


_PLY_TYPES = {"char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1", "short": "i2", "ushort": "u2",
              "int16": "i2", "uint16": "u2", "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _read_ply(path: Path) -> Mesh | None:
    """Fast path for binary little-endian PLY files with triangle faces (as we write them).

    Returns None for layouts it does not handle, so the caller falls back to pymeshlab."""
    with open(path, "rb") as f:
        header = []
        while True:
            line = f.readline()
            if not line:
                return None
            line = line.decode("ascii", errors="replace").strip()
            header.append(line)
            if line == "end_header":
                break
        if "format binary_little_endian 1.0" not in header:
            return None
        elements, current = [], None
        for line in header:
            parts = line.split()
            if parts[0] == "element":
                current = [parts[1], int(parts[2]), []]
                elements.append(current)
            elif parts[0] == "property" and current is not None:
                if parts[1] == "list":
                    if current[0] != "face":
                        return None
                    current[2].append(("list", parts[2], parts[3], parts[4]))
                else:
                    current[2].append((parts[2], _PLY_TYPES[parts[1]]))
        data = f.read()
    offset, vertex, faces = 0, None, None
    for name, count, props in elements:
        if name == "face":
            if len(props) != 1 or props[0][0] != "list":
                return None
            ct, it = _PLY_TYPES[props[0][1]], _PLY_TYPES[props[0][2]]
            dtype = np.dtype([("n", "<" + ct), ("i", "<" + it, (3,))])
            arr = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            if count and not np.all(arr["n"] == 3):
                return None
            faces = arr["i"].astype(np.int64)
        else:
            dtype = np.dtype([(p[0], "<" + p[1]) for p in props])
            arr = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            if name == "vertex":
                vertex = arr
        offset += dtype.itemsize * count
    if vertex is None or faces is None:
        return None
    names = vertex.dtype.names
    mesh = Mesh(np.stack([vertex["x"], vertex["y"], vertex["z"]], -1), faces)
    if all(c in names for c in ("red", "green", "blue")):
        cols = np.stack([vertex[c] for c in ("red", "green", "blue")], -1).astype(np.float32)
        mesh.vertex_colors = cols / 255.0 if vertex["red"].dtype == np.uint8 else cols
    for n in names:
        if n not in ("x", "y", "z", "red", "green", "blue"):
            mesh.attributes[n] = np.asarray(vertex[n], dtype=np.float32)
    return mesh


def ply_bytes(mesh: Mesh) -> bytes:
    """Binary PLY: float32 positions, float32 linear colours as red/green/blue, attributes."""
    return ply.ply_bytes(mesh.vertices, mesh.faces, mesh.vertex_colors, mesh.attributes)


def save_mesh(path: str | Path, mesh: Mesh) -> None:
    """Write PLY (binary) or OBJ (text) atomically."""
    path = Path(path)
    if path.suffix.lower() == ".obj":
        lines = [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in mesh.vertices]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
        fsio.write_text(path, "\n".join(lines) + "\n")
    else:
        fsio.write_bytes(path, ply_bytes(mesh))
