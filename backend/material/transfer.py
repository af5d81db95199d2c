"""Locating points on a triangle mesh: closest points and barycentrics (numpy + scipy KD-tree).

Used to carry material samples from an old mesh to a new one: exactly when the new mesh
lies on the old surface (midpoint subdivision), approximately after re-meshing."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentrics (n, 3) of the points of triangles (a, b, c) closest to points p (all (n, 3)).

    Ericson, Real-Time Collision Detection 5.1.5, vectorised over n."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    n = len(p)
    out = np.zeros((n, 3))
    done = np.zeros(n, bool)

    def put(mask, bary):
        nonlocal done
        mask = mask & ~done
        out[mask] = bary[mask] if np.ndim(bary) == 2 else bary
        done |= mask

    safe = lambda x: np.where(np.abs(x) < 1e-300, 1e-300, x)  # noqa: E731
    put((d1 <= 0) & (d2 <= 0), np.array([1.0, 0, 0]))
    put((d3 >= 0) & (d4 <= d3), np.array([0, 1.0, 0]))
    put((d6 >= 0) & (d5 <= d6), np.array([0, 0, 1.0]))
    v = d1 / safe(d1 - d3)
    put((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1 - v, v, 0 * v], 1))
    w = d2 / safe(d2 - d6)
    put((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1 - w, 0 * w, w], 1))
    w = (d4 - d3) / safe((d4 - d3) + (d5 - d6))
    put((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), np.stack([0 * w, 1 - w, w], 1))
    denom = 1.0 / safe(va + vb + vc)
    v, w = vb * denom, vc * denom
    put(np.ones(n, bool), np.stack([1 - v - w, v, w], 1))
    return out


def project_onto_faces(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                       face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barycentrics (n, 3) and distances of ``points`` to their given ``face`` of a mesh."""
    tri = vertices[faces[face]]
    bary = closest_on_triangles(points, tri[:, 0], tri[:, 1], tri[:, 2])
    closest = np.einsum("nk,nkd->nd", bary, tri)
    return bary, np.linalg.norm(points - closest, axis=1)


def locate(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, candidates: int = 16,
           tolerance: float = 1e-9, exhaustive: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest face, barycentrics (n, 3) and distance of each point on a triangle mesh.

    Candidates are the faces with the nearest centroids. A point left farther than
    ``tolerance`` (relative to the longest edge) is checked against every face with a
    vertex within (its distance + the longest edge), which contains the true closest face
    (unless ``exhaustive`` is off: then the best candidate is kept)."""
    points = np.asarray(points, float)
    k = min(candidates, len(faces))
    _, cand = cKDTree(vertices[faces].mean(1)).query(points, k=k)
    cand = cand.reshape(len(points), k)
    face = np.zeros(len(points), np.int64)
    bary = np.zeros((len(points), 3))
    dist = np.full(len(points), np.inf)
    for c in range(k):
        b, d = project_onto_faces(points, vertices, faces, cand[:, c])
        better = d < dist
        face[better], bary[better], dist[better] = cand[better, c], b[better], d[better]
    edge = float(np.linalg.norm(vertices[faces] - vertices[faces[:, [1, 2, 0]]], axis=2).max())
    unsure = np.flatnonzero(dist > tolerance * max(edge, 1e-12))
    if exhaustive and len(unsure) and k < len(faces):
        tree = cKDTree(vertices)
        order = np.argsort(faces.ravel(), kind="stable")
        start = np.searchsorted(faces.ravel()[order], np.arange(len(vertices) + 1))
        for i in unsure:
            verts = np.asarray(tree.query_ball_point(points[i], dist[i] + edge), np.int64)
            near = np.unique(np.concatenate([order[start[v]:start[v + 1]] // 3 for v in verts] or [[]]))
            near = near.astype(np.int64)
            if len(near) == 0:
                continue
            b, d = project_onto_faces(np.repeat(points[i:i + 1], len(near), 0), vertices, faces, near)
            j = int(np.argmin(d))
            if d[j] < dist[i]:
                face[i], bary[i], dist[i] = near[j], b[j], d[j]
    return face, bary, dist


def carry_vertex_material(source, target):
    """``target`` (a Mesh) with the per-vertex material of ``source`` (albedo colours,
    specular and roughness attributes) interpolated at each target vertex's closest point on
    ``source``: a fitted material carried onto another surface, e.g. the true geometry (what
    the geometry alone costs in PSNR)."""
    face, bary, _ = locate(target.vertices, source.vertices, source.faces, exhaustive=False)
    corners = source.faces[face]

    def carried(values):
        values = np.asarray(values, np.float64)
        flat = values.reshape(len(source.vertices), -1)
        out = (flat[corners] * bary[..., None]).sum(1)
        return out.reshape((len(target.vertices),) + values.shape[1:]).astype(values.dtype)

    out = target.copy()
    out.vertex_colors = None if source.vertex_colors is None else carried(source.vertex_colors)
    out.attributes = {k: v for k, v in target.attributes.items() if k not in source.attributes}
    out.attributes.update({k: carried(v) for k, v in source.attributes.items() if k in ("specular", "roughness")})
    return out
