"""Initial meshes: space carving, sphere or box proxies, a sphere cloud, a user mesh, or
SfM points + screened Poisson. ``initial_mesh(capture, "carve" | ... | FILE, faces, warn)``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...capture.model import Capture
from ...errors import InputError
from ..mesh import Mesh
from ..topology import enclosed
from .carve import carve
from .points_poisson import points_mesh
from .sphere import box_mesh, sphere_mesh
from .spheres import sphere_cloud
from .user_mesh import check_initial_mesh, user_mesh

KINDS = ("carve", "sphere", "box", "spheres", "points")


def default_kind(capture: Capture) -> str:
    """Carving when every frame has a mask, else the point cloud when there is one, else a sphere."""
    if capture.has_masks:
        return "carve"
    return "points" if capture.points is not None else "sphere"


def initial_mesh(capture: Capture, kind: str | None, faces: int, warn=lambda message: None) -> tuple[Mesh, str]:
    """The initial mesh (at most ``faces`` faces) and the kind used; ``kind`` may be a file."""
    kind = kind or default_kind(capture)
    cameras = [f.camera for f in capture.frames]
    if kind == "carve":
        cuts = []
        mesh = carve(capture, faces, cuts=cuts)
        for cut in cuts:
            p = cut.position
            warn(f"the visual hull enclosed the point light at ({p[0]:.3g}, {p[1]:.3g}, {p[2]:.3g}): the free space "
                 f"around it is carved away, open towards the cameras in {100 * cut.open_share:.0f}% of the "
                 "directions from it")
    elif kind == "sphere":
        mesh = sphere_mesh(capture, faces)
    elif kind == "box":
        mesh = box_mesh(capture, faces)
    elif kind == "spheres":
        mesh = sphere_cloud(capture, faces)
    elif kind == "points":
        mesh = points_mesh(capture, faces)
    else:
        path = Path(kind)
        if not path.is_file():
            raise InputError(path, f"'{kind}' is neither an initialisation ({', '.join(KINDS)}) nor a mesh file",
                             "give one of those names or an existing OBJ/PLY file")
        return user_mesh(path, cameras, faces, warn), str(path)
    return check_initial_mesh(mesh, kind, cameras, warn), kind


def check_lights_outside(capture: Capture, mesh: Mesh, kind: str) -> None:
    """A point light inside the starting surface leaves every render black and every
    gradient zero: such a run would learn nothing and must not end "done". (A carved start
    has the lights it enclosed carved out already; this guards the other starts.)"""
    lights = {tuple(np.round(light.position, 9)) for f in capture.frames for light in f.lights}
    if not lights:
        return
    positions = np.array(sorted(lights))
    inside = enclosed(mesh, positions)
    if inside.any():
        p = positions[np.argmax(inside)]
        raise InputError(capture.root, f"the initial mesh ({kind}) encloses the point light at "
                         f"({p[0]:.3g}, {p[1]:.3g}, {p[2]:.3g}): every render would be black",
                         "start from a mesh that leaves the lights outside (--init sphere or a mesh file), "
                         "or give masks that do not cover the lamp")
