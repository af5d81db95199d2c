"""Space carving: the visual hull of the object masks, meshed and simplified.

Works from a handful of views (the hull is looser with fewer); the default initialisation
whenever every frame has a mask. The pieces apart from the largest that no mask needs
(backend.geometry.pieces) are dropped."""

from __future__ import annotations

from ...capture.images import read_mask
from ...capture.model import Capture
from ..isosurface import marching_tetrahedra
from ..mesh import Mesh
from ..pieces import drop_unneeded_components
from ..simplify import simplify
from ..topology import keep_largest_components
from .hull import LEVEL, HullConfig, visual_hull


def carve(capture: Capture, faces: int = 5000, config: HullConfig | None = None) -> Mesh:
    """The visual hull as a closed manifold mesh with at most ``faces`` faces."""
    hull = visual_hull(capture, config)
    mesh = marching_tetrahedra(hull.values, LEVEL, hull.origin, hull.spacing)
    mesh = keep_largest_components(mesh, min_share=0.01)
    if all(f.mask is not None for f in capture.frames):
        mesh = drop_unneeded_components(mesh, [f.camera for f in capture.frames],
                                        [read_mask(f.mask) for f in capture.frames])
    return simplify(mesh, faces)
