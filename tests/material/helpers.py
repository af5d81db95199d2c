"""Small meshes and surface-point helpers shared by the material tests."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from backend.geometry.mesh import Mesh
from backend.synth import procedural


def lumpy(subdivisions: int = 1) -> Mesh:
    """A closed, irregular mesh (non-uniform triangles) about 1 unit across."""
    mesh = procedural.icosphere(subdivisions)
    x, y, z = mesh.vertices.T
    mesh.vertices = mesh.vertices * (1 + 0.2 * np.sin(3 * x + 2 * y) * np.cos(2 * z))[:, None]
    return mesh


def midpoint_subdivide(mesh: Mesh, seed: int = 0) -> tuple[Mesh, np.ndarray, np.ndarray]:
    """1 -> 4 midpoint split with shuffled vertex and face order.

    Returns the new mesh, each new face's parent, and the parent-barycentrics (3, 3) of
    each new face's corners (rows: corner, columns: weight of parent vertex 0, 1, 2)."""
    f = mesh.faces
    pairs = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), 1)
    uniq, inverse = np.unique(pairs, axis=0, return_inverse=True)
    mid = mesh.n_vertices + inverse.reshape(3, -1).T  # (F, 3): midpoints of v0v1, v1v2, v2v0
    vertices = np.vstack([mesh.vertices, 0.5 * (mesh.vertices[uniq[:, 0]] + mesh.vertices[uniq[:, 1]])])
    a, b, c = f.T
    ab, bc, ca = mid.T
    faces = np.concatenate([np.c_[a, ab, ca], np.c_[ab, b, bc], np.c_[ca, bc, c], np.c_[ab, bc, ca]])
    e = np.eye(3)
    h = lambda i, j: 0.5 * (e[i] + e[j])  # noqa: E731
    child_bary = np.array([[e[0], h(0, 1), h(2, 0)], [h(0, 1), e[1], h(1, 2)], [h(2, 0), h(1, 2), e[2]],
                           [h(0, 1), h(1, 2), h(2, 0)]])
    parent = np.tile(np.arange(mesh.n_faces), 4)
    corner_bary = np.repeat(child_bary, mesh.n_faces, 0)
    rng = np.random.default_rng(seed)
    vperm = rng.permutation(len(vertices))
    inv = np.empty_like(vperm)
    inv[vperm] = np.arange(len(vperm))
    fperm = rng.permutation(len(faces))
    new = Mesh(vertices[vperm], inv[faces][fperm])
    return new, parent[fperm], corner_bary[fperm]


def interaction(face, b1, b2) -> mi.SurfaceInteraction3f:
    """A surface interaction carrying (prim_index, uv = (b1, b2)) as Mitsuba fills it on a UV-less mesh."""
    si = dr.zeros(mi.SurfaceInteraction3f, len(face))
    si.prim_index = mi.UInt32(np.asarray(face, np.uint32))
    si.uv = mi.Point2f(np.asarray(b1, np.float32), np.asarray(b2, np.float32))
    return si


def lookup_numpy(material, face, b1, b2) -> dict[str, np.ndarray]:
    """The Dr.Jit field lookup at points, as numpy (n, width) arrays."""
    with dr.suspend_grad():
        albedo, spec, rough = material.field.lookup(interaction(face, b1, b2), mi.Bool(True))
    return {"albedo": np.array(albedo).T.reshape(-1, 3), "specular": np.array(spec).reshape(-1, 1),
            "roughness": np.array(rough).reshape(-1, 1)}


def random_points(n_faces: int, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Random faces and barycentrics (n, 3), uniform inside each triangle."""
    return rng.integers(0, n_faces, n), rng.dirichlet([1, 1, 1], n)


def three_plane_corner(n: int = 2) -> tuple[Mesh, np.ndarray]:
    """Floor z = 0 (label 0), wall x = 0 (label 1), wall y = 0 (label 2), each the unit square
    split into n x n quads, normals facing into the corner."""
    g = np.linspace(0.0, 1.0, n + 1)
    u, v = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    zero = np.zeros_like(u)
    planes = [np.c_[u, v, zero], np.c_[zero, u, v], np.c_[v, zero, u]]
    quad = np.array([(i * (n + 1) + j, (i + 1) * (n + 1) + j, (i + 1) * (n + 1) + j + 1, i * (n + 1) + j + 1)
                     for i in range(n) for j in range(n)])
    tris = np.concatenate([quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]])
    step = (n + 1) ** 2
    faces = np.concatenate([tris + k * step for k in range(3)])
    return Mesh(np.vstack(planes), faces), np.repeat(np.arange(3), len(tris))
