"""Mesh-color resolution from the frames' pixel footprint on each face (numpy; the ray casts
of ``labels.visible_centroids``).

A face seen by a camera of focal length f (pixels) from depth z shows an edge of length l
about f l / z pixels long. Its resolution r_f sets the sample spacing along that edge to
l / r_f, so r_f ~ its longest projected edge in pixels gives about one sample per pixel
(``spacing`` pixels per sample in general) in the view that sees it largest: the texture is
then as fine as the photos and no finer. A face counts as seen by a view when its centroid
is in front of the camera, inside the frame and the first hit along the ray from the camera
centre."""

from __future__ import annotations

import numpy as np

from ..capture.model import Camera
from ..geometry.mesh import Mesh
from ..geometry.raycast import RayCaster
from .labels import visible_centroids
from .meshcolors import MAX_RESOLUTION, samples_per_face


def face_footprints(mesh: Mesh, cameras: list[Camera]) -> np.ndarray:
    """(F,) each face's largest projected edge length in pixels over the cameras that see it
    (0 for a face no camera sees)."""
    caster = RayCaster(mesh)
    out = np.zeros(mesh.n_faces)
    corners = mesh.vertices[mesh.faces].reshape(-1, 3)
    for camera in cameras:
        _, seen = visible_centroids(mesh, camera, caster)
        uv, _ = camera.project(corners)
        uv = uv.reshape(-1, 3, 2)
        edges = np.linalg.norm(uv - np.roll(uv, -1, axis=1), axis=2).max(1)
        out = np.where(seen, np.maximum(out, edges), out)
    return out


def footprint_resolutions(footprint: np.ndarray, spacing: float = 1.0, max_samples: int | None = None,
                          lo: int = 1, hi: int = MAX_RESOLUTION) -> np.ndarray:
    """(F,) r_f = round(footprint / spacing) clamped to [lo, hi] (unseen faces get ``lo``).

    ``lo`` is 1, not 0: r = 1 stores nothing beyond the shared vertex samples, while r = 0
    would make the face one constant, discontinuous with its neighbours. With
    ``max_samples``, the resolutions are scaled down together until the faces' entries
    (sum of (r + 1)(r + 2) / 2, an upper bound on the samples) fit it."""
    r = np.clip(np.round(np.asarray(footprint, np.float64) / spacing), lo, hi).astype(np.int64)
    if max_samples is not None:
        scale = 1.0
        while int(samples_per_face(r).sum()) > max_samples and r.max() > lo:
            scale *= 0.9
            r = np.clip(np.round(np.asarray(footprint) * scale / spacing), lo, hi).astype(np.int64)
    return r
