"""Mesh colors (Yuksel et al. 2010) with a shared-sample layout (numpy side).

A triangle (v0, v1, v2) at resolution r >= 1 holds samples (i, j), i, j >= 0, i + j <= r, at
barycentric position b1 = i / r, b2 = j / r (p = (1 - b1 - b2) p0 + b1 p1 + b2 p2, Mitsuba's
convention, where si.uv = (b1, b2) on a mesh without UVs). Inside a triangle, sample (i, j)
has the paper's local index

    k(i, j) = i (2r - i + 3) / 2 + j,        0 <= k < K = (r + 1)(r + 2) / 2,

and the paper stores triangle t's samples at t K + k of one array. Here samples on vertices
and edges are *shared* instead, so the stored function is continuous by construction:

    [ V vertex samples | E (r - 1) edge samples | F (r - 1)(r - 2) / 2 interior samples ]

Edge e = (a, b), a < b, holds samples m = 1 .. r-1 at a + (m / r)(b - a). ``table`` is the
(F, K) map from the paper's per-triangle index to the shared array:
``table.ravel()[t K + k]`` is the shared sample the paper would store at t K + k.
r = 0 stores one value per face (``table = arange(F)[:, None]``).

Values are linear inside each of the r^2 sub-triangles: upright (i, j), (i+1, j), (i, j+1)
and inverted (i+1, j+1), (i, j+1), (i+1, j)."""

from __future__ import annotations

import numpy as np

MAX_RESOLUTION = 32


def local_index(i, j, r: int):
    """The paper's per-triangle sample index k(i, j) at resolution r."""
    return i * (2 * r - i + 3) // 2 + j


def local_samples(r: int) -> np.ndarray:
    """(K, 2) integer (i, j) of a triangle's samples, in local-index order."""
    if r == 0:
        return np.zeros((1, 2), np.int64)
    return np.array([(i, j) for i in range(r + 1) for j in range(r + 1 - i)], np.int64)


def unique_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges (E, 2) with a < b, and each face's edges (F, 3) for (v0v1, v1v2, v2v0)."""
    pairs = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], 1).reshape(-1, 2)
    edges, inverse = np.unique(np.sort(pairs, 1), axis=0, return_inverse=True)
    return edges, inverse.reshape(-1, 3)


def local_sub_triangles(r: int) -> np.ndarray:
    """(r^2, 3) local indices of a triangle's sub-triangles, oriented like the triangle."""
    if r == 0:
        raise ValueError("resolution 0 has no sub-triangles")
    k = local_index
    up = [(k(i, j, r), k(i + 1, j, r), k(i, j + 1, r)) for i in range(r) for j in range(r - i)]
    down = [(k(i + 1, j, r), k(i + 1, j + 1, r), k(i, j + 1, r)) for i in range(r - 1) for j in range(r - 1 - i)]
    return np.array(up + down, np.int64)


class MeshColorLayout:
    """Where each face's mesh-color samples live in the shared sample array."""

    def __init__(self, faces: np.ndarray, n_vertices: int, resolution: int):
        if not 0 <= resolution <= MAX_RESOLUTION:
            raise ValueError(f"mesh-color resolution must be in 0..{MAX_RESOLUTION}, not {resolution}")
        self.faces = np.asarray(faces, np.int64).reshape(-1, 3)
        self.n_vertices = int(n_vertices)
        self.resolution = r = int(resolution)
        self.local = local_samples(r)
        if r == 0:
            self.table = np.arange(self.n_faces, dtype=np.int64)[:, None]
            self.n_samples = self.n_faces
            return
        edges, face_edges = unique_edges(self.faces)
        self.n_edges = len(edges)
        n_interior = (r - 1) * (r - 2) // 2
        edge_base = self.n_vertices
        interior_base = edge_base + len(edges) * (r - 1)
        self.n_samples = interior_base + self.n_faces * n_interior
        table = np.empty((self.n_faces, len(self.local)), np.int64)
        interior = 0
        f = self.faces
        for k, (i, j) in enumerate(self.local):
            if (i, j) == (0, 0):
                table[:, k] = f[:, 0]
            elif (i, j) == (r, 0):
                table[:, k] = f[:, 1]
            elif (i, j) == (0, r):
                table[:, k] = f[:, 2]
            elif j == 0:  # edge v0 -> v1, step i
                table[:, k] = self._edge_sample(edge_base, face_edges[:, 0], f[:, 0], f[:, 1], i)
            elif i + j == r:  # edge v1 -> v2, step j
                table[:, k] = self._edge_sample(edge_base, face_edges[:, 1], f[:, 1], f[:, 2], j)
            elif i == 0:  # edge v2 -> v0, step r - j
                table[:, k] = self._edge_sample(edge_base, face_edges[:, 2], f[:, 2], f[:, 0], r - j)
            else:
                table[:, k] = interior_base + np.arange(self.n_faces) * n_interior + interior
                interior += 1
        self.table = table

    def _edge_sample(self, base, edge, start, end, step):
        """Shared index of the sample ``step``/r along the face edge start -> end."""
        r = self.resolution
        m = np.where(start < end, step, r - step)
        return base + edge * (r - 1) + (m - 1)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def samples_per_face(self) -> int:
        return self.table.shape[1]

    def local_barycentrics(self) -> np.ndarray:
        """(K, 2) (b1, b2) of a triangle's samples (the centroid for r = 0)."""
        if self.resolution == 0:
            return np.full((1, 2), 1.0 / 3.0)
        return self.local / float(self.resolution)

    def sample_sites(self) -> tuple[np.ndarray, np.ndarray]:
        """One (face, (b1, b2)) per shared sample where it can be evaluated.

        Unreferenced vertices get face -1."""
        face = np.full(self.n_samples, -1, np.int64)
        bary = np.zeros((self.n_samples, 2))
        F, K = self.table.shape
        face[self.table.ravel()] = np.repeat(np.arange(F), K)
        bary[self.table.ravel()] = np.tile(self.local_barycentrics(), (F, 1))
        return face, bary

    def sample_positions(self, vertices: np.ndarray) -> np.ndarray:
        """(n_samples, 3) world positions of the samples on a mesh with these faces."""
        face, bary = self.sample_sites()
        pos = np.zeros((self.n_samples, 3))
        ok = face >= 0
        tri = vertices[self.faces[face[ok]]]
        b1, b2 = bary[ok, 0:1], bary[ok, 1:2]
        pos[ok] = (1 - b1 - b2) * tri[:, 0] + b1 * tri[:, 1] + b2 * tri[:, 2]
        return pos

    def corners(self, face: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shared sample indices (n, 3) and weights (n, 3) interpolating at (face, b1, b2).

        The same arithmetic as the Dr.Jit lookup (backend.material.field)."""
        face = np.asarray(face, np.int64)
        r = self.resolution
        if r == 0:
            idx = self.table[face, 0]
            return np.stack([idx, idx, idx], 1), np.stack([np.ones(len(face)), np.zeros(len(face)),
                                                         np.zeros(len(face))], 1)
        x, y = np.clip(b1, 0, 1) * r, np.clip(b2, 0, 1) * r
        i = np.clip(np.floor(x).astype(np.int64), 0, r - 1)
        j = np.clip(np.floor(y).astype(np.int64), 0, r - 1 - i)
        fx, fy = x - i, y - j
        upper = (fx + fy > 1) & (i + j < r - 1)
        ka = np.where(upper, local_index(i + 1, j + 1, r), local_index(i, j, r))
        kb, kc = local_index(i, j + 1, r), local_index(i + 1, j, r)
        w = np.stack([np.where(upper, fx + fy - 1, 1 - fx - fy), np.where(upper, 1 - fx, fy),
                      np.where(upper, 1 - fy, fx)], 1)
        return self.table[face[:, None], np.stack([ka, kb, kc], 1)], w

    def evaluate(self, values: np.ndarray, face, b1, b2) -> np.ndarray:
        """Interpolate per-sample ``values`` (n_samples, ...) at points (face, b1, b2)."""
        idx, w = self.corners(face, b1, b2)
        values = np.asarray(values)
        w = w.reshape(w.shape + (1,) * (values.ndim - 1))
        return (values[idx] * w).sum(1)

    def sub_triangles(self) -> np.ndarray:
        """(F r^2, 3) shared sample indices of all sub-triangles, same orientation as the faces."""
        return self.table[:, local_sub_triangles(self.resolution)].reshape(-1, 3)
