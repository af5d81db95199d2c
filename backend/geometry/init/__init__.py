"""Initial meshes: space carving, sphere or box proxies, a sphere cloud, a user mesh, or
SfM points + screened Poisson. ``initial_mesh(capture, "carve" | ... | FILE, faces, warn)``;
``cached_initial_mesh`` keeps what it made beside the capture for the capture's later runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...capture import probe_cache
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


CACHE = "initial_mesh"
CACHE_ENTRIES = 4  # initial meshes a capture keeps (each a few hundred kB of JSON)


def cached_initial_mesh(capture: Capture, kind: str | None, faces: int, warn=lambda message: None) -> tuple[Mesh, str]:
    """``initial_mesh``, taken from ``CAPTURE/.sft-cache/initial_mesh.json`` when an earlier run
    made it from the same capture content, kind (a file: its size and time), face count and
    code (``backend/geometry``), with the warnings it gave then; else made and kept there.
    The mesh is the same to the bit (floats kept at full precision)."""
    given = Path(kind) if kind and kind not in KINDS else None
    stat = given.stat() if given is not None and given.is_file() else None
    key = probe_cache.key(capture, kind=kind or default_kind(capture), faces=int(faces),
                          file=None if stat is None else [str(given.resolve()), stat.st_size, stat.st_mtime_ns],
                          code=probe_cache.code_version(Path(__file__).parents[1]))
    entry = probe_cache.load(capture, CACHE, key)
    if isinstance(entry, dict):
        try:
            mesh = Mesh(np.array(entry["vertices"], np.float64), np.array(entry["faces"], np.int64))
            for message in entry.get("warnings", []):
                warn(message)
            return mesh, str(entry["kind"])
        except (KeyError, TypeError, ValueError):
            pass
    warnings: list[str] = []

    def kept(message: str) -> None:
        warnings.append(message)
        warn(message)

    mesh, used = initial_mesh(capture, kind, faces, kept)
    if mesh.vertex_colors is None and not mesh.attributes:  # only what the entry holds
        probe_cache.store(capture, CACHE, key, {"kind": used, "warnings": warnings, "vertices": mesh.vertices,
                                                "faces": mesh.faces}, most=CACHE_ENTRIES)
    return mesh, used


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
