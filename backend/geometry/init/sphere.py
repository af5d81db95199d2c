"""Proxy shapes: a sphere fitted to the masks (or the cameras' focus) and a box around the hull."""

from __future__ import annotations

import numpy as np

from ...capture.images import read_mask
from ...capture.model import Capture
from ..mesh import Mesh
from ..primitives import icosphere
from ..topology import clean
from .hull import HullConfig, hull_box, mask_views


def fit_sphere(capture: Capture) -> tuple[np.ndarray, float]:
    """Centre and radius of the sphere whose projections best match the masks.

    The centre is the least-squares meeting point of the rays through the mask centroids;
    each view's radius follows from its mask area (a sphere at distance d with image
    radius rho pixels has radius d sin(atan(rho / f))); the median over views is taken.
    Without masks: the cameras' focus with half the radius they frame."""
    if not capture.has_masks:
        centre, radius = capture.bounds_hint()
        return centre, 0.5 * radius
    A, b, rays = np.zeros((3, 3)), np.zeros(3), []
    for frame in capture.frames:
        mask = read_mask(frame.mask) > 0.5
        ys, xs = np.nonzero(mask)
        if len(xs) == 0:
            continue
        cam = frame.camera
        u, v = xs.mean() + 0.5, ys.mean() + 0.5
        d_cam = np.array([(u - cam.cx) / cam.fx, -(v - cam.cy) / cam.fy, -1.0])  # OpenGL camera axes
        d = cam.camera_to_world[:3, :3] @ d_cam
        d /= np.linalg.norm(d)
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.centre
        rays.append((cam, np.sqrt(len(xs) / np.pi)))
    centre = np.linalg.lstsq(A, b, rcond=None)[0]
    radii = [np.linalg.norm(cam.centre - centre) * np.sin(np.arctan(rho / cam.fx)) for cam, rho in rays]
    return centre, float(np.median(radii))


def sphere_mesh(capture: Capture, faces: int = 5000) -> Mesh:
    """An icosphere (at most ``faces`` faces, at least 320) fitted to the masks."""
    centre, radius = fit_sphere(capture)
    level = max(2, int(np.floor(np.log(max(faces, 20) / 20) / np.log(4))))
    mesh = icosphere(level, radius)
    mesh.vertices += centre
    return mesh


def box_mesh(capture: Capture, faces: int = 5000) -> Mesh:
    """A closed box with a regular grid of triangles on each side: the visual hull's bounding
    box when masks exist, else a cube around the fitted sphere."""
    if capture.has_masks:
        lo, hi = hull_box(capture, mask_views(capture), HullConfig())
    else:
        centre, radius = fit_sphere(capture)
        lo, hi = centre - radius, centre + radius
    n = max(1, int(np.sqrt(faces / 12)))
    return _grid_box(lo, hi, n)


def _grid_box(lo: np.ndarray, hi: np.ndarray, n: int) -> Mesh:
    t = np.linspace(0.0, 1.0, n + 1)
    verts, faces = [], []
    offset = 0
    for axis in range(3):
        for side in (0, 1):
            a, b = [(axis + 1) % 3, (axis + 2) % 3]
            U, V = np.meshgrid(t, t, indexing="ij")
            p = np.zeros((n + 1, n + 1, 3))
            p[..., axis] = side
            p[..., a], p[..., b] = U, V
            idx = offset + np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
            q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
            tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
            faces.append(tris if side == 1 else tris[:, ::-1])
            verts.append(p.reshape(-1, 3))
            offset += (n + 1) ** 2
    v = np.concatenate(verts)
    f = np.concatenate(faces)
    uniq, inverse = np.unique(np.round(v * 4 * n).astype(np.int64), axis=0, return_inverse=True)
    merged = np.zeros((len(uniq), 3))
    merged[inverse.ravel()] = v
    return clean(Mesh(lo + merged * (hi - lo), inverse.ravel()[f]))
