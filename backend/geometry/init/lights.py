"""Point lights inside the visual hull: the free space around each carved away.

A point light is in free space, but the visual hull can enclose it: when every view sees the
object behind the lamp (a lamp in a corner of two walls and a floor seen from one side, a lamp
before a backdrop) the lamp projects inside every mask. A start that encloses the lamp renders
black wherever the cameras look, and every gradient is zero.

The cut is star-shaped about the lamp L. Along each of ``DIRECTIONS`` directions u the ray
from L leaves the hull at Q(u) = L + e(u) u. Where some camera sees Q (the segment from Q to
the camera stays outside the hull) and Q is nearer to that camera than the lamp, Q lies on the
side of the hull facing the cameras, between them and the lamp: the ray is carved through, to e(u) + 2 cells. Elsewhere Q lies behind what
the cameras see (behind the walls): the ray is carved to e(u) - ``SHELL_CELLS`` cells (at least
to e(u) / 2), so a shell of the hull's far side stays, facing the lamp. The carved radius is
interpolated between directions and applied to the hull field as a signed distance.

Why this shape: the cameras must look at surface the lamp lights. A ball or a tunnel to each
camera frees the lamp, but leaves the cameras looking at the hull's outer faces, which the
lamp lights from behind: black again. Opening every direction that the cameras see leaves them
looking into the cavity at its far side, which faces the lamp. The object lies inside the hull,
behind the lamp from the cameras, so the shell keeps it; the masks cannot say how deep behind
the walls the hull reaches beyond the object, so the start lies at that depth and the
optimisation brings it forward.

The guard: the object fills every mask, so a cut of free space leaves every silhouette whole;
directions whose opening uncovers mask pixels are closed again (the shell kept where those
pixels' rays leave the hull). A lamp at the centre of a closed object seen from all round has
every direction closed that way, or a few tunnels left open: it stays enclosed, or the cameras
see the object's outside, which the lamp lights from within. So where, after the cut, the
lamp is still enclosed, more than ``MAX_LOST`` of a mask is uncovered, or less than
``MIN_LIT`` of the masks' pixels see surface facing the lamp, the lamp lies inside the object,
not in the free space before it: a capture error, raised as one line."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ...capture.model import Camera, Capture
from ...errors import InputError
from ..isosurface import marching_tetrahedra
from ..mesh import Mesh
from ..raycast import RayCaster, pixel_rays
from ..topology import enclosed
from .hull import LEVEL, HullField, MaskView

DIRECTIONS = 8192
SHELL_CELLS = 6.0  # thickness of the far side kept behind the lamp
OPEN_CELLS = 2.0  # how far past the hull's boundary a direction the cameras see is carved
MAX_LOST = 0.05  # share of a view's mask pixels the cut may uncover (the outline's pixels, at a few dozen px)
ROUNDS = 3  # rounds of closing the directions that uncover mask pixels
MIN_LIT = 0.5  # share of the masks' pixels that must see surface facing a freed light
CLOSE_NEIGHBOURS = 8  # directions closed around each uncovering pixel's far point


@dataclass
class LightCut:
    position: np.ndarray
    open_share: float  # share of the directions from the lamp carved through to the cameras
    lost: float  # the largest share of a view's mask the cut uncovered

    def event(self) -> dict:
        return {"position": [round(float(x), 6) for x in self.position], "open_share": round(self.open_share, 4),
                "lost": round(self.lost, 4)}


def light_positions(capture: Capture) -> np.ndarray:
    """The distinct point-light positions (M, 3) of all frames."""
    lights = {tuple(np.round(light.position, 9)) for f in capture.frames for light in f.lights}
    return np.array(sorted(lights), float).reshape(-1, 3)


def _inside(field: HullField, points: np.ndarray) -> np.ndarray:
    """Whether ``points`` (N, 3) are inside the hull (trilinear field value above the level)."""
    idx = ((np.asarray(points, float) - field.origin) / field.spacing).T
    values = ndimage.map_coordinates(field.values, idx, order=1, mode="constant", cval=0.0)
    return values > LEVEL


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit directions (a Fibonacci spiral)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(np.clip(1 - z * z, 0, 1))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def _mesh(field: HullField) -> Mesh:
    return marching_tetrahedra(field.values, LEVEL, field.origin, field.spacing)


def carved_radius(caster: RayCaster, field: HullField, light: np.ndarray, cameras: list[Camera],
                  directions: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """The carved distances along each of ``directions`` from ``light`` (inside the hull),
    open (through the hull) and closed (to the shell), and
    whether that direction is open: its exit point seen by a camera, nearer to it than the
    lamp (every point of a visual hull's boundary lies on some view's silhouette cone, so a
    camera grazes even the far side; only a point before the lamp is between it and a camera)."""
    hits = caster.intersect(light, directions)
    extent = float(np.linalg.norm(np.array(field.values.shape) * field.spacing))
    exit = np.where(hits.hit, hits.distance, extent)
    start = light + directions * (exit + 0.5 * field.spacing)[:, None]  # just outside the hull
    seen = ~hits.hit  # a ray that never meets the hull again is open
    for camera in cameras:
        to = camera.centre - start
        length = np.linalg.norm(to, axis=1)
        back = caster.intersect(start, to / length[:, None])
        _, depth = camera.project(start)
        _, lamp_depth = camera.project(light[None])
        seen |= (~back.hit | (back.distance >= length)) & (depth < lamp_depth[0])
    through = exit + OPEN_CELLS * field.spacing
    shell = np.maximum(exit - SHELL_CELLS * field.spacing, 0.5 * exit)
    return (through, shell), seen


def _cut_field(field: HullField, light: np.ndarray, directions: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """The field with the star-shaped region {light + t u : t < radius(u)} removed."""
    points = field.points()
    offset = points - light
    distance = np.linalg.norm(offset, axis=1)
    near = distance < radius.max() + 2 * field.spacing
    u = offset[near] / np.maximum(distance[near], 1e-12)[:, None]
    dist, idx = cKDTree(directions).query(u, k=4)
    w = 1.0 / np.maximum(dist, 1e-6)
    r = (radius[idx] * w).sum(1) / w.sum(1)
    ramp = np.ones(len(points), np.float32)
    ramp[near] = np.clip(LEVEL + (distance[near] - r) / (2 * field.spacing), 0.0, 1.0)
    return np.minimum(field.values, ramp.reshape(field.values.shape))


def _uncovered(before: RayCaster, after: Mesh, views: list[MaskView], reach: float) -> tuple[float, np.ndarray]:
    """The largest share of a view's mask pixels that ``before`` covers and ``after`` does
    not, and where those pixels' rays last leave ``before`` (the hull's far side)."""
    caster = RayCaster(after) if after.n_faces else None
    worst, far = 0.0, []
    for view in views:
        mask = view.mask.reshape(-1) > LEVEL
        o, d = pixel_rays(view.camera)
        o, d = np.broadcast_to(o, d.shape)[mask], d[mask]
        lost = before.intersect(o, d).hit
        if caster is not None:
            lost &= ~caster.intersect(o, d).hit
        worst = max(worst, float(lost.sum()) / max(int(mask.sum()), 1))
        if lost.any():
            back = before.intersect(o[lost] + reach * d[lost], -d[lost])  # from beyond the hull, backwards
            far.append(back.points[back.hit])
    return worst, np.concatenate(far) if far else np.zeros((0, 3))


def lit_share(mesh: Mesh, views: list[MaskView], lights: np.ndarray) -> float:
    """The share of all views' mask pixels whose first hit on ``mesh`` faces one of ``lights``
    from the camera's side (the side the camera sees)."""
    caster = RayCaster(mesh)
    lit = total = 0
    for view in views:
        mask = view.mask.reshape(-1) > LEVEL
        o, d = pixel_rays(view.camera)
        o, d = np.broadcast_to(o, d.shape)[mask], d[mask]
        hits = caster.intersect(o, d)
        facing = hits.shading_towards(d)[hits.hit]
        towards = lights[None, :, :] - hits.points[hits.hit][:, None, :]
        lit += int(((facing[:, None, :] * towards).sum(-1) > 0).any(1).sum())
        total += int(mask.sum())
    return lit / max(total, 1)


def free_lights(field: HullField, views: list[MaskView], lights: np.ndarray, root) -> tuple[Mesh, list[LightCut]]:
    """The hull's surface with the free space around every light it encloses carved away, and
    the cuts made. Directions whose carving uncovers mask pixels are closed again (the shell
    kept where those pixels' rays leave the hull), for up to ``ROUNDS`` rounds. Raises
    :class:`InputError` when a light stays enclosed or a mask stays uncovered: the light lies
    inside the object."""
    enclosed_lights = lights[_inside(field, lights)] if len(lights) else lights
    whole = _mesh(field)
    if not len(enclosed_lights):
        return whole, []
    before = RayCaster(whole)
    directions = fibonacci_sphere(DIRECTIONS)
    tree = cKDTree(directions)
    cameras = [v.camera for v in views]
    reach = float(np.linalg.norm(np.array(field.values.shape) * field.spacing)) + max(
        float(np.linalg.norm(c.centre - field.origin)) for c in cameras)
    cuts = [carved_radius(before, field, light, cameras, directions) for light in enclosed_lights]
    for _ in range(ROUNDS + 1):
        values = field.values
        for light, (radius, seen) in zip(enclosed_lights, cuts):
            r = np.where(seen, radius[0], radius[1])
            values = _cut_field(HullField(values, field.origin, field.spacing), light, directions, r)
        mesh = _mesh(HullField(values, field.origin, field.spacing))
        lost, far = _uncovered(before, mesh, views, reach)
        if lost <= MAX_LOST or not len(far):
            break
        closed = 0
        for light, (radius, seen) in zip(enclosed_lights, cuts):
            u = far - light
            _, idx = tree.query(u / np.maximum(np.linalg.norm(u, axis=1), 1e-12)[:, None], k=CLOSE_NEIGHBOURS)
            idx = np.unique(idx)
            closed += int(seen[idx].sum())
            seen[idx] = False
        if not closed:
            break
    inside = enclosed(mesh, enclosed_lights) if mesh.n_faces else np.ones(len(enclosed_lights), bool)
    lit = lit_share(mesh, views, enclosed_lights) if mesh.n_faces else 0.0
    if lost > MAX_LOST or inside.any() or lit < MIN_LIT:
        p = enclosed_lights[int(np.argmax(inside))] if inside.any() else enclosed_lights[0]
        why = (f"carving the free space around it uncovers {100 * lost:.0f}% of a mask" if lost > MAX_LOST
               else "no free space around it reaches the cameras" if inside.any()
               else f"the cameras would see only {100 * lit:.0f}% of their masks lit by it")
        raise InputError(root, f"the visual hull encloses the point light at ({p[0]:.3g}, {p[1]:.3g}, {p[2]:.3g}) "
                         f"and {why}: the light lies inside the object",
                         "check the light's position in capture.json against the cameras (a lamp stands in "
                         "free space), or start from a mesh that leaves it outside (--init FILE)")
    return mesh, [LightCut(light.copy(), float(seen.mean()), lost) for light, (_, seen) in zip(enclosed_lights, cuts)]
