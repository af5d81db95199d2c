"""Mesh colors (Yuksel et al. 2010) with a shared-sample layout (numpy side).

A triangle (v0, v1, v2) at resolution r >= 1 holds samples (i, j), i, j >= 0, i + j <= r, at
barycentric position b1 = i / r, b2 = j / r (p = (1 - b1 - b2) p0 + b1 p1 + b2 p2, Mitsuba's
convention, where si.uv = (b1, b2) on a mesh without UVs). Inside a triangle, sample (i, j)
has the paper's local index

    k(i, j) = i (2r - i + 3) / 2 + j,        0 <= k < K = (r + 1)(r + 2) / 2,

and the paper stores triangle t's samples at t K + k of one array. Here samples on vertices
and edges are *shared* instead, so the stored function is continuous by construction:

    [ V vertex samples | edge samples | interior samples, (r - 1)(r - 2) / 2 per face ]

Edge e = (a, b), a < b, at resolution r holds samples m = 1 .. r-1 at a + (m / r)(b - a).
r = 0 stores one value per face and no vertex samples.

**Per-face resolution.** Each face f may have its own r_f (``resolution`` an (F,) array): its
K_f entries sit at ``entries[offsets[f] : offsets[f + 1]]`` in local-index order, so the
lookup is the uniform one with r and the base offset gathered per face (one kernel, no
branch per resolution class; ``field.corners_mixed``). Vertex samples are shared by every
face. An edge's samples are shared by the faces on it that have the same r (one block per
(edge, r) pair): across an edge between faces of unequal r the function is continuous at
the two vertices only, each side interpolating its own samples. A mixed layout needs every
r_f >= 1 (an r = 0 face is a constant, discontinuous everywhere; r = 1 stores no samples
beyond the shared vertices). With one r for every face, ``table`` is the (F, K) map from the
paper's per-triangle index to the shared array (``table.ravel()[t K + k]`` is the sample the
paper would store at t K + k), and the numbering is the uniform layout's.

Values are linear inside each of the r^2 sub-triangles: upright (i, j), (i+1, j), (i, j+1)
and inverted (i+1, j+1), (i, j+1), (i+1, j)."""

from __future__ import annotations

import numpy as np

MAX_RESOLUTION = 32


def local_index(i, j, r):
    """The paper's per-triangle sample index k(i, j) at resolution r (scalars or arrays)."""
    return i * (2 * r - i + 3) // 2 + j


def samples_per_face(r):
    """K = (r + 1)(r + 2) / 2 entries of a face at resolution r (1 at r = 0)."""
    return (r + 1) * (r + 2) // 2


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
    """Where each face's mesh-color samples live in the shared sample array.

    ``resolution``: one r for every face, or an (F,) array of per-face r_f (module docstring).
    Attributes: ``resolutions`` (F,), ``offsets`` (F + 1,) and ``entries`` (sum K_f,), the
    shared sample of each face's local index; ``resolution`` the largest r_f; ``uniform``;
    ``table`` (F, K) when uniform."""

    def __init__(self, faces: np.ndarray, n_vertices: int, resolution):
        self.faces = np.asarray(faces, np.int64).reshape(-1, 3)
        self.n_vertices = int(n_vertices)
        F = len(self.faces)
        res = np.asarray(resolution, np.int64)
        if res.ndim == 0:
            res = np.full(F, int(res), np.int64)
        if res.shape != (F,):
            raise ValueError(f"{res.size} mesh-color resolutions for {F} faces")
        if F and (res.min() < 0 or res.max() > MAX_RESOLUTION):
            bad = int(res.min() if res.min() < 0 else res.max())
            raise ValueError(f"mesh-color resolution must be in 0..{MAX_RESOLUTION}, not {bad}")
        self.uniform = bool(F == 0 or res.min() == res.max())
        if not self.uniform and res.min() == 0:
            raise ValueError("a layout with per-face resolutions needs every resolution >= 1")
        self.resolutions = res
        self.resolution = int(res.max()) if F else int(np.asarray(resolution).max(initial=0))
        K = samples_per_face(res)
        self.offsets = np.concatenate([[0], np.cumsum(K)]).astype(np.int64)
        entries = np.empty(int(self.offsets[-1]), np.int64)
        if self.uniform and self.resolution == 0:
            entries[:] = np.arange(F)
            self.n_samples = F
            self._finish(entries)
            return
        edges, face_edges = unique_edges(self.faces)
        self.n_edges = len(edges)
        # one block of r - 1 samples per (edge, r) pair that some face uses, ordered by edge then r
        key = face_edges * (MAX_RESOLUTION + 1) + res[:, None]
        keys, key_index = np.unique(key.ravel(), return_inverse=True)
        key_index = key_index.reshape(F, 3)
        block = np.concatenate([[0], np.cumsum(keys % (MAX_RESOLUTION + 1) - 1)])
        edge_base = self.n_vertices
        interior_base = edge_base + int(block[-1])
        n_interior = (res - 1) * (res - 2) // 2
        interior_start = interior_base + np.concatenate([[0], np.cumsum(n_interior)])[:-1]
        self.n_samples = interior_base + int(n_interior.sum())
        for r in np.unique(res):
            r = int(r)
            fs = np.flatnonzero(res == r)
            f, fe = self.faces[fs], key_index[fs]
            cols = self.offsets[fs][:, None] + np.arange(samples_per_face(r))[None]
            rows = np.empty((len(fs), samples_per_face(r)), np.int64)

            def edge_sample(side, start, end, step):
                m = np.where(start < end, step, r - step)
                return edge_base + block[fe[:, side]] + (m - 1)

            interior = 0
            for k, (i, j) in enumerate(local_samples(r)):
                if (i, j) == (0, 0):
                    rows[:, k] = f[:, 0]
                elif (i, j) == (r, 0):
                    rows[:, k] = f[:, 1]
                elif (i, j) == (0, r):
                    rows[:, k] = f[:, 2]
                elif j == 0:  # edge v0 -> v1, step i
                    rows[:, k] = edge_sample(0, f[:, 0], f[:, 1], i)
                elif i + j == r:  # edge v1 -> v2, step j
                    rows[:, k] = edge_sample(1, f[:, 1], f[:, 2], j)
                elif i == 0:  # edge v2 -> v0, step r - j
                    rows[:, k] = edge_sample(2, f[:, 2], f[:, 0], r - j)
                else:
                    rows[:, k] = interior_start[fs] + interior
                    interior += 1
            entries[cols.ravel()] = rows.ravel()
        self._finish(entries)

    def _finish(self, entries: np.ndarray) -> None:
        self.entries = entries
        self.entry_face = np.repeat(np.arange(self.n_faces), np.diff(self.offsets))
        self.table = entries.reshape(self.n_faces, -1) if self.uniform else None

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def samples_per_face(self) -> int:
        """K of a uniform layout (the largest K_f of a mixed one)."""
        return samples_per_face(self.resolution)

    def local_barycentrics(self) -> np.ndarray:
        """(K, 2) (b1, b2) of a uniform layout's triangle samples (the centroid for r = 0)."""
        if self.resolution == 0:
            return np.full((1, 2), 1.0 / 3.0)
        return local_samples(self.resolution) / float(self.resolution)

    def entry_barycentrics(self) -> np.ndarray:
        """(sum K_f, 2) (b1, b2) of every entry, face by face in local-index order."""
        out = np.empty((len(self.entries), 2))
        for r in np.unique(self.resolutions):
            r = int(r)
            fs = np.flatnonzero(self.resolutions == r)
            local = np.full((1, 2), 1.0 / 3.0) if r == 0 else local_samples(r) / float(r)
            cols = self.offsets[fs][:, None] + np.arange(len(local))[None]
            out[cols.ravel()] = np.tile(local, (len(fs), 1))
        return out

    def face_means(self, values: np.ndarray) -> np.ndarray:
        """(F, ...) mean of each face's entries of per-sample ``values``."""
        values = np.asarray(values)
        sums = np.add.reduceat(values[self.entries], self.offsets[:-1], axis=0)
        counts = np.diff(self.offsets).reshape((-1,) + (1,) * (values.ndim - 1))
        return sums / counts

    def sample_sites(self) -> tuple[np.ndarray, np.ndarray]:
        """One (face, (b1, b2)) per shared sample where it can be evaluated.

        Unreferenced vertices get face -1."""
        face = np.full(self.n_samples, -1, np.int64)
        bary = np.zeros((self.n_samples, 2))
        face[self.entries] = self.entry_face
        bary[self.entries] = self.entry_barycentrics()
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
        r = self.resolutions[face]
        base = self.offsets[face]
        if self.uniform and self.resolution == 0:
            idx = self.entries[base]
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
        return self.entries[base[:, None] + np.stack([ka, kb, kc], 1)], w

    def evaluate(self, values: np.ndarray, face, b1, b2) -> np.ndarray:
        """Interpolate per-sample ``values`` (n_samples, ...) at points (face, b1, b2)."""
        idx, w = self.corners(face, b1, b2)
        values = np.asarray(values)
        w = w.reshape(w.shape + (1,) * (values.ndim - 1))
        return (values[idx] * w).sum(1)

    def sub_triangle_entries(self) -> np.ndarray:
        """(sum r_f^2, 3) entry positions (into ``entries``) of all sub-triangles, face by face,
        oriented like the faces."""
        if self.resolutions.min(initial=1) == 0:
            raise ValueError("resolution 0 has no sub-triangles")
        out = np.empty((int((self.resolutions ** 2).sum()), 3), np.int64)
        start = np.concatenate([[0], np.cumsum(self.resolutions ** 2)])
        for r in np.unique(self.resolutions):
            r = int(r)
            fs = np.flatnonzero(self.resolutions == r)
            subs = local_sub_triangles(r)
            rows = start[fs][:, None] + np.arange(len(subs))[None]
            out[rows.ravel()] = (self.offsets[fs][:, None, None] + subs[None]).reshape(-1, 3)
        return out

    def sub_triangles(self) -> np.ndarray:
        """(sum r_f^2, 3) shared sample indices of all sub-triangles, same orientation as the faces."""
        return self.entries[self.sub_triangle_entries()]
