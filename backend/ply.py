"""Binary little-endian PLY encoding of per-vertex arrays and triangles.

Shared by mesh output (:func:`backend.geometry.mesh.save_mesh`) and a capture's point cloud
(:func:`backend.capture.importers.colmap.write_points`), so neither package needs the other.
Positions, colours and attributes are float32; colours are linear and written as
``red``/``green``/``blue``; faces are a ``uchar int`` list (3 per face)."""

from __future__ import annotations

import numpy as np


def ply_bytes(vertices: np.ndarray, faces: np.ndarray | None = None, colors: np.ndarray | None = None,
              attributes: dict[str, np.ndarray] | None = None) -> bytes:
    """The PLY file of ``vertices`` (V, 3), optional ``faces`` (F, 3), ``colors`` (V, 3) and
    named per-vertex ``attributes`` (V,); a point cloud when ``faces`` is None or empty."""
    vertices = np.asarray(vertices).reshape(-1, 3)
    faces = np.zeros((0, 3), np.int64) if faces is None else np.asarray(faces).reshape(-1, 3)
    attributes = attributes or {}
    n = len(vertices)
    cols = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        cols += [("red", "<f4"), ("green", "<f4"), ("blue", "<f4")]
    cols += [(k, "<f4") for k in attributes]
    v = np.empty(n, dtype=cols)
    v["x"], v["y"], v["z"] = vertices.T.astype(np.float32)
    if colors is not None:
        v["red"], v["green"], v["blue"] = np.asarray(colors, np.float32).T
    for k, a in attributes.items():
        v[k] = a
    f = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    f["n"] = 3
    f["i"] = faces
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name, _ in cols]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(header) + "\n").encode() + v.tobytes() + f.tobytes()
