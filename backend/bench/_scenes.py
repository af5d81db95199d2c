"""Test objects and captures the geometry benchmark and tests build themselves."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..capture.format import save_capture
from ..capture.images import write_image, write_mask
from ..capture.model import Camera, Capture, Frame, PointLight
from ..geometry.mesh import Mesh, save_mesh
from ..geometry.raycast import RayCaster
from ..render.fields import ConstantField
from ..render.scene import RenderSettings, SceneRenderer
from ..synth.layout import look_at
from ..synth.procedural import icosphere


def torus(major: float = 1.0, minor: float = 0.35, n_major: int = 48, n_minor: int = 24) -> Mesh:
    """A closed genus-1 torus around the Z axis, wound outward."""
    a = np.linspace(0, 2 * np.pi, n_major, endpoint=False)
    b = np.linspace(0, 2 * np.pi, n_minor, endpoint=False)
    A, B = np.meshgrid(a, b, indexing="ij")
    v = np.stack([(major + minor * np.cos(B)) * np.cos(A), (major + minor * np.cos(B)) * np.sin(A),
                  minor * np.sin(B)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    p00 = i * n_minor + j
    p10 = ((i + 1) % n_major) * n_minor + j
    p01 = i * n_minor + (j + 1) % n_minor
    p11 = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor
    f = np.concatenate([np.stack([p00, p10, p11], -1).reshape(-1, 3), np.stack([p00, p11, p01], -1).reshape(-1, 3)])
    return Mesh(v, f)


def divot_sphere(depth: float, width: float, subdivisions: int = 5, axis=(1.0, 0.0, 0.0)) -> Mesh:
    """A unit sphere with a smooth Gaussian dent of ``depth`` (radial) and angular ``width``
    (radians) around ``axis``."""
    mesh = icosphere(subdivisions)
    d = mesh.vertices
    angle = np.arccos(np.clip(d @ np.asarray(axis, float), -1, 1))
    mesh.vertices = d * (1.0 - depth * np.exp(-(angle / width) ** 2))[:, None]
    return mesh


def cone_cameras(axis, count: int, spread_deg: float, distance: float, resolution: int, fov_deg: float) -> list[Camera]:
    """One camera on ``axis`` and ``count - 1`` around it at ``spread_deg``, looking at the origin."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    dirs = [axis]
    s = np.radians(spread_deg)
    for k in range(count - 1):
        phi = 2 * np.pi * k / (count - 1)
        dirs.append(np.cos(s) * axis + np.sin(s) * (np.cos(phi) * u + np.sin(phi) * w))
    f = 0.5 * resolution / np.tan(np.radians(fov_deg) / 2)
    return [Camera(resolution, resolution, f, f, resolution / 2, resolution / 2, look_at(distance * d, np.zeros(3)))
            for d in dirs]


def render_capture(out: Path, mesh: Mesh, frames: list[tuple[Camera, list[PointLight]]], albedo, specular: float,
                   roughness: float, spp: int = 64, seed: int = 0) -> Capture:
    """Render ``mesh`` (constant material, point lights, black background) into a capture
    folder with masks and ``gt/mesh.ply`` as ground truth."""
    out = Path(out)
    field = ConstantField(albedo, specular, roughness)
    cams = [c for c, _ in frames]
    lights = [ls for _, ls in frames]
    renderer = SceneRenderer(mesh, field, cams, lights, None, RenderSettings(spp=spp, max_depth=4), rgba=True)
    out_frames = []
    for i, (cam, ls) in enumerate(frames):
        rgba = renderer.render_numpy(i, seed=seed * 1000 + i)
        image, mask = out / "images" / f"{i:04d}.exr", out / "masks" / f"{i:04d}.png"
        write_image(image, rgba[..., :3])
        write_mask(mask, rgba[..., 3])
        out_frames.append(Frame(f"{i:04d}", image, cam, mask=mask, lights=ls))
    save_mesh(out / "gt" / "mesh.ply", mesh)
    capture = Capture(out, out_frames, ground_truth={"mesh": "gt/mesh.ply"},
                      provenance={"source": "bench", "albedo": list(np.broadcast_to(albedo, 3).astype(float)),
                                  "specular": specular, "roughness": roughness})
    save_capture(capture)
    return capture


def divot_capture(out: Path, depth: float = 0.15, width: float = 0.35, resolution: int = 128,
                  cameras: int = 5, lights: int = 4) -> Capture:
    """The shape-from-shading case: a sphere with a dent that no silhouette shows, seen by
    ``cameras`` cameras within 25 degrees of the dent, each under ``lights`` light positions."""
    axis = np.array([1.0, 0.0, 0.0])
    mesh = divot_sphere(depth, width, axis=axis)
    cams = cone_cameras(axis, cameras, 25.0, 4.0, resolution, 36.0)
    light_dirs = cone_cameras(axis, lights + 1, 35.0, 4.0, 8, 30.0)[1:]
    frames = [(cam, [PointLight(lc.centre, np.full(3, 12.0))]) for cam in cams for lc in light_dirs]
    return render_capture(out, mesh, frames, albedo=0.6, specular=0.1, roughness=0.5)


def radial_profile(mesh: Mesh, directions: np.ndarray) -> np.ndarray:
    """Distance from the origin to the surface along each unit direction (first hit)."""
    far = 10.0 * float(np.abs(mesh.vertices).max())
    hits = RayCaster(mesh).intersect(directions * far, -directions)
    return np.where(hits.hit, np.linalg.norm(hits.points, axis=1), np.nan)


def divot_depth(mesh: Mesh, width: float, axis=(1.0, 0.0, 0.0)) -> float:
    """Depth of the dent of a divot sphere: radius on a ring 3 widths out minus radius at its centre."""
    axis = np.asarray(axis, float)
    cam = cone_cameras(axis, 17, np.degrees(3 * width), 1.0, 8, 30.0)
    ring = np.array([c.centre for c in cam[1:]])
    r = radial_profile(mesh, np.vstack([axis[None], ring]))
    return float(np.nanmean(r[1:]) - r[0])
