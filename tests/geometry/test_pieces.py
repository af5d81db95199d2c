"""Pieces no mask needs (backend.geometry.pieces), with real ray casts: a floater inside the
object's silhouette in every view goes, a part beside the object stays."""

from __future__ import annotations

import numpy as np

from backend import variant

variant.choose()

from backend.geometry.mesh import Mesh  # noqa: E402
from backend.geometry.pieces import drop_unneeded_components  # noqa: E402
from backend.geometry.raycast import RayCaster, pixel_rays  # noqa: E402
from backend.synth.layout import orbit_cameras  # noqa: E402
from backend.synth.procedural import icosphere  # noqa: E402


def test_pieces_no_mask_needs_are_dropped_and_a_part_beside_is_kept():
    """Views from one side: a small piece in front of the object, inside its silhouette in every
    view, explains no mask pixel and is dropped; a part beside the object, in the masks, stays."""
    def at(mesh: Mesh, radius: float, centre) -> Mesh:
        return Mesh(mesh.vertices * (radius / 0.5) + np.asarray(centre, float), mesh.faces)

    def joined(*meshes: Mesh) -> Mesh:
        offsets = np.cumsum([0] + [m.n_vertices for m in meshes[:-1]])
        return Mesh(np.concatenate([m.vertices for m in meshes]),
                    np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]))

    body = icosphere(3, 0.5)
    side = at(icosphere(2, 0.5), 0.15, (0.0, 0.8, 0.0))
    floater = at(icosphere(2, 0.5), 0.06, (0.75, 0.0, 0.0))
    angles = np.radians([-10, -5, 0, 5, 10])
    directions = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], 1)
    cams = orbit_cameras(directions, np.zeros(3), 1.0, 48)
    truth = RayCaster(joined(body, side))  # what the masks show: the object and its part
    masks = [truth.intersect(*pixel_rays(c)).hit.reshape(c.height, c.width).astype(np.float32) for c in cams]
    out = drop_unneeded_components(joined(body, side, floater), cams, masks)
    assert out.n_faces == body.n_faces + side.n_faces
    assert out.vertices[:, 0].max() < 0.55  # the floater (out to x = 0.81) is gone
    assert out.vertices[:, 1].max() > 0.9  # the part beside (up to y = 0.95) stays
    assert drop_unneeded_components(body, cams, masks) is body
