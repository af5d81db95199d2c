"""Space carving: the visual hull of the object masks, meshed and simplified.

Works from a handful of views (the hull is looser with fewer); the default initialisation
whenever every frame has a mask. A point light the hull encloses gets a ball of free space
around it carved away (``lights.free_lights``), so the start leaves every light outside. The
pieces apart from the largest that no mask needs (backend.geometry.pieces) are dropped."""

from __future__ import annotations

from ...capture.images import read_mask
from ...capture.model import Capture
from ..mesh import Mesh
from ..pieces import drop_unneeded_components
from ..simplify import simplify
from ..topology import keep_largest_components
from .hull import HullConfig, mask_views, visual_hull
from .lights import free_lights, light_positions


def carve(capture: Capture, faces: int = 5000, config: HullConfig | None = None, cuts: list | None = None) -> Mesh:
    """The visual hull, freed of the point lights it encloses, as a closed manifold mesh with
    at most ``faces`` faces. ``cuts``, when given, receives the light cuts made."""
    views = mask_views(capture)
    hull = visual_hull(capture, config, views)
    mesh, made = free_lights(hull, views, light_positions(capture), capture.root)
    if cuts is not None:
        cuts.extend(made)
    mesh = keep_largest_components(mesh, min_share=0.01)
    if all(f.mask is not None for f in capture.frames):
        mesh = drop_unneeded_components(mesh, [f.camera for f in capture.frames],
                                        [read_mask(f.mask) for f in capture.frames])
    return simplify(mesh, faces)
