"""Ray casting against one mesh with Mitsuba, and the rays of a camera's pixels.

One pixel convention throughout (as ``Camera.project`` and docs/capture-format.md): pixel
(x, y) covers [x, x + 1) x [y, y + 1) from the image's top-left corner, and its ray passes
through the pixel's centre (x + 0.5, y + 0.5). Choose the Mitsuba variant
(``backend.variant.choose()``) before building a :class:`RayCaster`."""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from ..capture.model import CV_TO_GL, Camera
from .mesh import Mesh


def mitsuba_mesh(mesh: Mesh, bsdf, name: str = "object") -> mi.Mesh:
    """``mesh`` as a Mitsuba mesh with ``bsdf``; its own shading normals when it has them."""
    props = mi.Properties()
    props["bsdf"] = bsdf
    m = mi.Mesh(name, mesh.n_vertices, mesh.n_faces, props=props, has_vertex_normals=True)
    params = mi.traverse(m)
    params["vertex_positions"] = mi.Float(mesh.vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(mesh.faces.astype(np.uint32).ravel())
    params.update()
    normals = mesh.shading_normals
    if normals is not None:  # a display mesh's own (Phong) normals, not the recomputed ones
        params["vertex_normals"] = mi.Float(np.asarray(normals, np.float32).ravel())
        params.update()
    return m


def pixel_rays(camera: Camera, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World origins (N, 3) and unit directions (N, 3) of the rays through the centres of
    ``pixels`` (N, 2) = integer (x, y); by default every pixel, rows top to bottom."""
    if pixels is None:
        v, u = np.mgrid[0:camera.height, 0:camera.width]
        pixels = np.c_[u.ravel(), v.ravel()]
    pixels = np.asarray(pixels, np.float64)
    d_cv = np.c_[(pixels[:, 0] + 0.5 - camera.cx) / camera.fx, (pixels[:, 1] + 0.5 - camera.cy) / camera.fy,
                 np.ones(len(pixels))]
    d = d_cv @ (camera.camera_to_world[:3, :3] @ CV_TO_GL[:3, :3]).T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.broadcast_to(camera.centre, d.shape).copy(), d


@dataclass
class Hits:
    """First hits of N rays (rows of a miss hold Mitsuba's placeholder values)."""

    hit: np.ndarray  # (N,) bool
    points: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3) geometric, outward by the faces' winding
    shading_normals: np.ndarray  # (N, 3) unit, interpolated vertex normals
    distance: np.ndarray  # (N,) along the (unit) ray
    face: np.ndarray  # (N,) index of the face hit

    def shading_towards(self, directions: np.ndarray) -> np.ndarray:
        """The shading normals flipped to face the rays' origins."""
        return self.shading_normals * np.where((self.shading_normals * directions).sum(1) > 0, -1.0, 1.0)[:, None]


class RayCaster:
    """Ray casts against one mesh."""

    def __init__(self, mesh: Mesh):
        self.scene = mi.load_dict({"type": "scene", "object": mitsuba_mesh(mesh, mi.load_dict({"type": "diffuse"}))})
        lo, hi = mesh.bounds()
        self.epsilon = 1e-4 * float(np.linalg.norm(hi - lo))  # offset of secondary rays off the surface

    @staticmethod
    def _rays(origins: np.ndarray, directions: np.ndarray):
        o = np.broadcast_to(np.asarray(origins, np.float32), np.shape(directions))
        d = np.asarray(directions, np.float32)
        return mi.Ray3f(mi.Point3f(*[np.ascontiguousarray(o[:, i]) for i in range(3)]),
                        mi.Vector3f(*[np.ascontiguousarray(d[:, i]) for i in range(3)]))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """First hits of rays from ``origins`` ((N, 3) or one point) along unit ``directions`` (N, 3)."""
        si = self.scene.ray_intersect(self._rays(origins, directions))
        shading = np.array(si.sh_frame.n, np.float64).T
        shading /= np.maximum(np.linalg.norm(shading, axis=1, keepdims=True), 1e-12)
        return Hits(np.array(si.is_valid(), bool), np.array(si.p, np.float64).T, np.array(si.n, np.float64).T,
                    shading, np.array(si.t, np.float64), np.array(si.prim_index, np.int64))

    def escapes(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Whether rays leave the mesh without hitting it."""
        return ~np.array(self.scene.ray_test(self._rays(origins, directions)), bool)
