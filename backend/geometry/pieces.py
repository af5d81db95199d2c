"""Pieces of a mesh that no mask needs.

A visual hull keeps every region that each view sees inside its mask or does not see at all:
with views from one side, or frames that crop the object, that leaves floaters beside the
object which no fitted view can remove, and which a view the fit never had sees outside the
mask."""

from __future__ import annotations

import numpy as np

from ..capture.model import Camera
from .mesh import Mesh
from .raycast import RayCaster, pixel_rays
from .topology import clean, face_components

NEEDED_MASK_SHARE = 0.01  # of a view's mask that a piece must alone cover to be kept


def drop_unneeded_components(mesh: Mesh, cameras: list[Camera], masks: list[np.ndarray],
                             needed_share: float = NEEDED_MASK_SHARE) -> Mesh:
    """``mesh`` without the pieces (connected components other than the largest) that no mask
    needs. A piece is needed where it is the first hit of a pixel inside the mask that the
    largest piece does not cover; it is kept when, in some view, such pixels make up
    ``needed_share`` of the mask. A floater that every view sees inside the object's silhouette
    or not at all explains nothing the masks ask for, and shows outside the mask from views the
    fit never had; a separate part beside the object fills mask pixels of its own."""
    n, labels = face_components(mesh)
    if n <= 1:
        return mesh
    largest = int(np.argmax(np.bincount(labels)))
    main = Mesh(mesh.vertices, mesh.faces[labels == largest])
    whole, alone = RayCaster(mesh), RayCaster(main)
    needed = np.zeros(n, bool)
    needed[largest] = True
    for cam, mask in zip(cameras, masks):
        o, d = pixel_rays(cam)
        inside = np.asarray(mask).reshape(-1) > 0.5
        first = whole.intersect(o, d)
        uncovered = inside & first.hit & ~alone.intersect(o, d).hit
        counts = np.bincount(labels[first.face[uncovered]], minlength=n)
        needed |= counts >= needed_share * max(int(inside.sum()), 1)
    if needed.all():
        return mesh
    return clean(Mesh(mesh.vertices, mesh.faces[needed[labels]]))
