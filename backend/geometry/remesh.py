"""Re-meshing by ray casting and screened Poisson reconstruction.

The current surface is sampled where the input cameras see it (first hits of one ray per
pixel, through Mitsuba's ``scene.ray_intersect``). Hits on back faces (the ray enters the
surface from inside: inverted or self-intersecting sheets) and hits that project outside a
mask in any view that sees them (geometry the silhouettes forbid, such as a membrane over a
hole) are dropped. Screened Poisson reconstruction of the remaining oriented points gives a
closed manifold without interior or self-intersecting triangles, whose genus may differ
from the input's. Screened Poisson closes every gap, including the one the dropped hits left
over a hole, so the result is then cut to the visual hull (its intersection with the masks'
cones) and simplified to the face target.

A handle shows in the images as a hole in some mask that the views see through.
``handles_supported`` tells whether a rebuilt surface that has more handles than the current
one lets the views see through more of the masks' holes; where it does not, the handles are
the hull cut's own (tunnels that the cones of several silhouettes leave between them, which
no single view sees through) and ``rebuild`` refuses the surface."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..capture.model import Camera
from .init.hull import HullConfig, MaskView, grid_points, sample
from .isosurface import marching_tetrahedra
from .mesh import Mesh
from .poisson import SurfaceReconstructionError, depth_for_resolution, poisson
from .raycast import RayCaster, pixel_rays
from .sampling import sample_surface
from .simplify import edge_length_for_faces, simplify
from .topology import inspect, keep_largest_components


@dataclass
class RemeshConfig:
    mask_tolerance_px: float = 1.5  # samples further outside a mask than this are dropped
    cells_per_edge: float = 1.5  # Poisson octree cells per target edge length
    max_depth: int = 10
    point_weight: float = 4.0


@dataclass
class VisibleSamples:
    points: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3), outward
    rays: int  # rays cast
    back_faces: int  # hits dropped because the ray met a back face
    outside_masks: int  # hits dropped by the masks


def outside_distance(mask: np.ndarray) -> np.ndarray:
    """Per pixel, the distance in pixels to the nearest object pixel (0 on the object)."""
    return ndimage.distance_transform_edt(mask <= 0.5)


def visible_samples(mesh: Mesh, cameras: list[Camera], masks: list[np.ndarray] | None,
                   config: RemeshConfig | None = None) -> VisibleSamples:
    """Oriented points on the visible, silhouette-consistent part of ``mesh``."""
    config = config or RemeshConfig()
    rays = [pixel_rays(c) for c in cameras]
    o = np.concatenate([r[0] for r in rays])
    d = np.concatenate([r[1] for r in rays])
    hits = RayCaster(mesh).intersect(o, d)
    valid, p, n = hits.hit, hits.points, hits.normals
    front = np.einsum("ij,ij->i", n, d) < 0
    back_faces = int(np.sum(valid & ~front))
    keep = valid & front
    p, n = p[keep], n[keep]
    dropped = 0
    if masks is not None:
        ok = np.ones(len(p), bool)
        for cam, mask in zip(cameras, masks):
            dist = outside_distance(mask)
            uv, depth = cam.project(p)
            h, w = mask.shape
            px = np.floor(uv).astype(np.int64)
            inframe = (depth > 0) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
            far = np.zeros(len(p), bool)
            far[inframe] = dist[px[inframe, 1], px[inframe, 0]] > config.mask_tolerance_px
            ok &= ~far
        dropped = int(np.sum(~ok))
        p, n = p[ok], n[ok]
    return VisibleSamples(p, n, len(o), back_faces, dropped)


def mask_holes(mask: np.ndarray) -> np.ndarray:
    """The background pixels the object encloses in ``mask`` (not connected to the frame's
    border): where a view sees through the object."""
    background = mask <= 0.5
    labels, _ = ndimage.label(background)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    return background & ~np.isin(labels, border)


def see_through(mesh: Mesh, cameras: list[Camera], masks: list[np.ndarray]) -> int:
    """How many mask-hole pixels (``mask_holes``) the rays of their cameras pass through
    ``mesh`` without a hit."""
    caster, seen = RayCaster(mesh), 0
    for cam, mask in zip(cameras, masks):
        holes = mask_holes(mask)
        if not holes.any():
            continue
        y, x = np.nonzero(holes)
        o, d = pixel_rays(cam, np.c_[x, y])
        seen += int(np.sum(~caster.intersect(o, d).hit))
    return seen


def handles_supported(old: Mesh, new: Mesh, cameras: list[Camera], masks: list[np.ndarray] | None,
                      min_pixels: int = 8) -> dict:
    """Whether the handles ``new`` has beyond ``old``'s are seen in the images: every handle
    added must let the views see through at least ``min_pixels`` more mask-hole pixels
    (``see_through``; 8: a hole of 2 x 2 pixels in two views, as one view's hole may be an
    error of its mask). Returns {"supported", "genus_before", "genus_after", "see_through_before",
    "see_through_after"}; a rebuilt surface with no more handles is always supported."""
    before, after = inspect(old).genus, inspect(new).genus
    out = {"genus_before": before, "genus_after": after, "see_through_before": None, "see_through_after": None}
    added = (after or 0) - (before or 0)
    if added <= 0 or before is None:
        return {"supported": True, **out}
    if masks is None:
        return {"supported": False, **out}
    out["see_through_before"] = seen_old = see_through(old, cameras, masks)
    out["see_through_after"] = seen_new = see_through(new, cameras, masks)
    return {"supported": seen_new - seen_old >= min_pixels * added, **out}


def signed_distance(mesh: Mesh, points: np.ndarray, samples: int = 200_000) -> np.ndarray:
    """Approximate signed distance (negative inside) of ``points`` to a closed mesh: the
    distance to the nearest of dense surface samples, signed by that sample's face normal."""
    s = sample_surface(mesh, samples, seed=0)
    normals = mesh.face_normals()[s.faces]
    d, i = cKDTree(s.points).query(points, workers=-1)
    side = np.einsum("ij,ij->i", points - s.points[i], normals[i])
    return np.where(side < 0, -d, d)


def clip_to_masks(mesh: Mesh, cameras: list[Camera], masks: list[np.ndarray], spacing: float,
                  max_cells: int = 160) -> Mesh:
    """The part of a closed mesh that projects inside every mask (its intersection with the
    visual hull), meshed on a grid of about ``spacing``: what the silhouettes forbid (a
    membrane over a hole) is cut away, so the genus can grow."""
    lo, hi = mesh.bounds()
    spacing = max(spacing, float((hi - lo).max()) / max_cells)
    lo, hi = lo - 3 * spacing, hi + 3 * spacing
    pts, shape, spacing = grid_points(lo, hi, int(np.ceil(float((hi - lo).max()) / spacing)))
    occupancy = np.clip(0.5 - signed_distance(mesh, pts) / (2 * spacing), 0.0, 1.0)
    views = [MaskView(c, m) for c, m in zip(cameras, masks)]
    hull = sample(views, pts, HullConfig(min_view_share=0.0))
    field = np.minimum(occupancy, hull).reshape(shape)
    return keep_largest_components(marching_tetrahedra(field, 0.5, lo, spacing), 0.02)


def poisson_from_samples(samples: VisibleSamples, mesh: Mesh, target_faces: int,
                         config: RemeshConfig | None = None, cameras: list[Camera] | None = None,
                         masks: list[np.ndarray] | None = None) -> Mesh:
    """Screened Poisson surface of the samples at the resolution of ``target_faces`` faces
    over ``mesh``'s area, cut to the masks when given, simplified to at most ``target_faces``."""
    config = config or RemeshConfig()
    lo, hi = mesh.bounds()
    spacing = edge_length_for_faces(mesh, target_faces) / config.cells_per_edge
    depth = depth_for_resolution(float((hi - lo).max()), spacing, hi=config.max_depth)
    rebuilt = poisson(samples.points, samples.normals, depth=depth, point_weight=config.point_weight)
    if masks is not None and cameras is not None:
        rebuilt = clip_to_masks(rebuilt, cameras, masks, spacing)
    return simplify(rebuilt, target_faces)


def rebuild(samples: VisibleSamples, mesh: Mesh, target_faces: int, cameras: list[Camera],
            masks: list[np.ndarray] | None, config: RemeshConfig | None = None) -> tuple[Mesh, dict]:
    """``poisson_from_samples``, checked: a closed manifold whose handles beyond ``mesh``'s are
    seen through in the masks (``handles_supported``, returned with the surface). Raises
    SurfaceReconstructionError otherwise: the current surface should stay."""
    rebuilt = poisson_from_samples(samples, mesh, target_faces, config, cameras, masks)
    report = inspect(rebuilt)
    if not report.closed_manifold:  # too few consistent samples (a tangled mesh): Poisson leaves holes
        raise SurfaceReconstructionError(f"the rebuilt surface is not a closed manifold ({', '.join(report.issues)})")
    handles = handles_supported(mesh, rebuilt, cameras, masks)
    if not handles["supported"]:  # the cut to the hull left tunnels the images do not show
        raise SurfaceReconstructionError(
            f"the rebuilt surface adds {handles['genus_after'] - handles['genus_before']} handles "
            f"(genus {handles['genus_before']} -> {handles['genus_after']}) that no view sees through")
    return rebuilt, handles


def remesh(mesh: Mesh, cameras: list[Camera], masks: list[np.ndarray] | None, target_faces: int,
           config: RemeshConfig | None = None) -> tuple[Mesh, VisibleSamples]:
    """Rebuild ``mesh`` from its ray-cast samples; at most ``target_faces`` faces."""
    samples = visible_samples(mesh, cameras, masks, config)
    return poisson_from_samples(samples, mesh, target_faces, config, cameras, masks), samples

