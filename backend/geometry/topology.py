"""Mesh topology: edges, Euler characteristic and genus, manifold checks, cleaning and repair."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .mesh import Mesh


def edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges (E, 2) (sorted pairs) and how many faces use each."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq, counts


def face_components(mesh: Mesh) -> tuple[int, np.ndarray]:
    """Connected components of faces sharing a vertex: (count, label per face)."""
    F = mesh.n_faces
    if F == 0:
        return 0, np.zeros(0, np.int64)
    rows = np.repeat(np.arange(F), 3)
    cols = F + mesh.faces.ravel()
    n = F + mesh.n_vertices
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    face_labels = labels[:F]
    uniq, face_labels = np.unique(face_labels, return_inverse=True)
    return len(uniq), face_labels


def euler_characteristic(mesh: Mesh) -> int:
    """V - E + F over the vertices the faces use."""
    used = len(np.unique(mesh.faces))
    return int(used - len(edges(mesh.faces)[0]) + mesh.n_faces)


@dataclass
class TopologyReport:
    vertices: int
    faces: int
    components: int
    euler: int
    boundary_edges: int
    nonmanifold_edges: int
    nonmanifold_vertices: int
    inconsistent_edges: int  # interior edges whose two faces disagree on orientation
    degenerate_faces: int
    issues: list[str] = field(default_factory=list)

    @property
    def closed_manifold(self) -> bool:
        return not (self.boundary_edges or self.nonmanifold_edges or self.nonmanifold_vertices
                    or self.inconsistent_edges)

    @property
    def genus(self) -> int | None:
        """Total genus of a closed orientable manifold: sum over components of (2 - chi_i) / 2."""
        if not self.closed_manifold:
            return None
        return (2 * self.components - self.euler) // 2


def _nonmanifold_vertices(faces: np.ndarray, n_vertices: int) -> int:
    """Vertices whose incident faces form more than one fan (e.g. two cones touching at a tip).

    Corners (face, vertex) are linked when their faces share an edge through that vertex;
    a vertex is manifold when all its corners end up in one connected group."""
    F = len(faces)
    k = np.arange(3)
    start = (3 * np.arange(F)[:, None] + k).ravel()  # corner of each half-edge's start vertex
    end = (3 * np.arange(F)[:, None] + (k + 1) % 3).ravel()
    corner_vertex = faces.ravel()
    key = np.sort(np.stack([corner_vertex[start], corner_vertex[end]], 1), axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    same = np.all(key[order][1:] == key[order][:-1], axis=1)
    h1, h2 = order[:-1][same], order[1:][same]
    aligned = corner_vertex[start[h1]] == corner_vertex[start[h2]]
    rows = np.concatenate([start[h1], end[h1]])
    cols = np.concatenate([np.where(aligned, start[h2], end[h2]), np.where(aligned, end[h2], start[h2])])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(3 * F, 3 * F))
    _, fan = connected_components(graph, directed=False)
    pairs = np.unique(np.stack([corner_vertex, fan], 1), axis=0)
    fans = np.bincount(pairs[:, 0], minlength=n_vertices)
    return int(np.sum(fans > 1))


def inspect(mesh: Mesh) -> TopologyReport:
    """Counts that decide whether a mesh is a clean closed 2-manifold, and its genus."""
    faces = mesh.faces
    if mesh.n_faces == 0:
        return TopologyReport(mesh.n_vertices, 0, 0, 0, 0, 0, 0, 0, 0, ["no faces"])
    uniq, counts = edges(faces)
    degenerate = int(np.sum((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
                            | (faces[:, 2] == faces[:, 0])))
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    inconsistent = int(np.sum(dcounts > 1))
    n_comp, _ = face_components(mesh)
    report = TopologyReport(
        vertices=mesh.n_vertices, faces=mesh.n_faces, components=n_comp,
        euler=euler_characteristic(mesh), boundary_edges=int(np.sum(counts == 1)),
        nonmanifold_edges=int(np.sum(counts > 2)),
        nonmanifold_vertices=_nonmanifold_vertices(faces, mesh.n_vertices) if not degenerate else 0,
        inconsistent_edges=inconsistent, degenerate_faces=degenerate)
    for name in ("boundary_edges", "nonmanifold_edges", "nonmanifold_vertices", "inconsistent_edges",
                 "degenerate_faces"):
        if getattr(report, name):
            report.issues.append(f"{getattr(report, name)} {name.replace('_', ' ')}")
    return report


def genus(mesh: Mesh) -> int | None:
    """Genus of a closed orientable manifold mesh (None when the mesh is not one)."""
    return inspect(mesh).genus


def clean(mesh: Mesh, area_eps: float = 0.0) -> Mesh:
    """Drop degenerate and duplicate faces and unreferenced vertices (attributes follow)."""
    f = mesh.faces
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    if area_eps > 0:
        keep &= mesh.face_areas() > area_eps
    f = f[keep]
    _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    f = f[np.sort(first)]
    used = np.unique(f)
    remap = np.full(mesh.n_vertices, -1, np.int64)
    remap[used] = np.arange(len(used))
    out = Mesh(mesh.vertices[used], remap[f],
               None if mesh.vertex_colors is None else mesh.vertex_colors[used],
               {k: v[used] for k, v in mesh.attributes.items()})
    return out


def keep_largest_components(mesh: Mesh, min_share: float = 0.05) -> Mesh:
    """Keep the components holding at least ``min_share`` of the faces (always the largest)."""
    n, labels = face_components(mesh)
    if n <= 1:
        return mesh
    sizes = np.bincount(labels)
    keep = sizes >= max(min_share * mesh.n_faces, 1)
    keep[np.argmax(sizes)] = True
    return clean(Mesh(mesh.vertices, mesh.faces[keep[labels]]))


def repair(mesh: Mesh) -> tuple[Mesh, list[str]]:
    """Make a mesh a closed, consistently oriented manifold where pymeshlab can; returns the
    repaired mesh and a list of what was done (empty when nothing was needed)."""
    report = inspect(clean(mesh))
    notes = []
    mesh = clean(mesh, area_eps=0.0)
    if report.closed_manifold:
        return mesh, notes
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(mesh.vertices, mesh.faces))
    ms.meshing_remove_duplicate_vertices()
    ms.meshing_remove_duplicate_faces()
    if report.nonmanifold_edges:
        ms.meshing_repair_non_manifold_edges(method="Remove Faces")
        notes.append(f"removed faces at {report.nonmanifold_edges} non-manifold edges")
    if report.nonmanifold_vertices:
        ms.meshing_repair_non_manifold_vertices()
        notes.append(f"split {report.nonmanifold_vertices} non-manifold vertices")
    if report.inconsistent_edges:
        ms.meshing_re_orient_faces_coherently()
        notes.append("re-oriented faces coherently")
    m = ms.current_mesh()
    if inspect(Mesh(m.vertex_matrix(), m.face_matrix())).boundary_edges:
        ms.meshing_close_holes(maxholesize=max(30, m.face_number() // 10), selfintersection=False)
        notes.append("closed holes")
    m = ms.current_mesh()
    return _drop_open_pieces(clean(Mesh(m.vertex_matrix(), m.face_matrix())), notes), notes


def _drop_open_pieces(mesh: Mesh, notes: list[str]) -> Mesh:
    """Drop components that are still open (stray triangles, flaps) when a closed one exists."""
    n, labels = face_components(mesh)
    if n <= 1:
        return mesh
    closed = np.array([inspect(Mesh(mesh.vertices, mesh.faces[labels == k])).boundary_edges == 0 for k in range(n)])
    if closed.all() or not closed.any():
        return mesh
    notes.append(f"dropped {int(np.sum(~closed))} open pieces ({int(np.sum(~closed[labels]))} faces)")
    return clean(Mesh(mesh.vertices, mesh.faces[closed[labels]]))


def orient_outward(mesh: Mesh) -> Mesh:
    """Flip a closed mesh whose signed volume is negative (faces wound inward)."""
    v = mesh.vertices[mesh.faces]
    volume = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0
    if volume < 0:
        out = mesh.copy()
        out.faces = mesh.faces[:, ::-1].copy()
        return out
    return mesh


def enclosed(mesh: Mesh, points: np.ndarray) -> np.ndarray:
    """Which ``points`` (N, 3) lie inside the mesh: generalised winding number above 1/2
    (either orientation; exact for closed meshes, robust to small holes)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    inside = np.zeros(len(points), bool)
    lo, hi = mesh.bounds()
    candidates = np.nonzero(np.all((points >= lo) & (points <= hi), axis=1))[0]  # outside the box: outside
    tri = mesh.vertices[mesh.faces] if len(candidates) else None
    for i in candidates:
        a, b, c = (tri[:, k] - points[i] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        num = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la
               + np.einsum("ij,ij->i", c, a) * lb)
        inside[i] = abs(np.arctan2(num, den).sum()) / (2 * np.pi) > 0.5  # solid angles / 4 pi
    return inside


def mean_edge_length(mesh: Mesh) -> float:
    e, _ = edges(mesh.faces)
    return float(np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1).mean())
