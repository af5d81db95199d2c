"""The open colour-bleeding corner: a grey floor beside a red and a blue wall, one lamp.

Three unit squares meet at the origin: the floor z = 0, the red wall x = 0 and the blue wall
y = 0, each facing into the corner (an open surface, one-sided). Every camera looks into the
corner from its open side; the lamp hangs inside the corner, so every view sees a wall or the
floor behind it and the visual hull of the masks encloses it. Near each wall the floor is
tinted by the light the wall throws onto it: a reconstruction that renders one bounce only
explains the tint as albedo.

:func:`write_open_corner` renders the capture (frames with their masks, the lamp in each
frame's ``lights``, and the truth in ``gt/``) into an empty folder."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..capture.format import save_capture
from ..capture.images import write_image, write_mask
from ..capture.model import Capture, Frame, PointLight
from ..geometry.mesh import Mesh, save_mesh
from ..geometry.raycast import RayCaster
from ..render.fields import VertexField
from ..render.scene import RenderSettings, SceneRenderer
from .. import fsio
from . import layout

FLOOR = (0.7, 0.7, 0.7)
RED = (0.75, 0.08, 0.06)  # the wall x = 0
BLUE = (0.08, 0.12, 0.75)  # the wall y = 0


@dataclass
class CornerSpec:
    views: int = 12
    resolution: int = 64
    spp: int = 256
    max_depth: int = 8
    cone_deg: float = 28.0  # half-angle of the cap of view directions around the open diagonal
    lamp: list[float] = field(default_factory=lambda: [0.45, 0.45, 0.6])
    intensity: float = 0.8  # W/sr
    cells: int = 8  # quads along a square's side (the truth's vertex colours)
    seed: int = 0


def corner_mesh(cells: int = 8) -> tuple[Mesh, np.ndarray, np.ndarray]:
    """The three squares (vertices not shared between them), their per-vertex albedo and a
    per-vertex label (0 floor, 1 red wall x = 0, 2 blue wall y = 0); normals into the corner."""
    g = np.linspace(0.0, 1.0, cells + 1)
    u, v = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    zero = np.zeros_like(u)
    planes = [np.c_[u, v, zero], np.c_[zero, u, v], np.c_[v, zero, u]]  # floor, x wall, y wall
    quads = np.array([(i * (cells + 1) + j, (i + 1) * (cells + 1) + j, (i + 1) * (cells + 1) + j + 1,
                       i * (cells + 1) + j + 1) for i in range(cells) for j in range(cells)])
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    step = (cells + 1) ** 2
    mesh = Mesh(np.vstack(planes), np.concatenate([tris + k * step for k in range(3)]))
    labels = np.repeat(np.arange(3), step)
    albedo = np.asarray([FLOOR, RED, BLUE], np.float32)[labels]
    return mesh, albedo, labels


def cap_directions(n: int, cone_deg: float, offset: float = 0.0) -> np.ndarray:
    """``n`` unit directions spread over the cap of half-angle ``cone_deg`` around the corner's
    open diagonal (1, 1, 1) / sqrt(3)."""
    i = np.arange(n) + 0.5 + offset
    z = 1 - (1 - np.cos(np.radians(cone_deg))) * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(np.clip(1 - z * z, 0, 1))
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)
    axis = np.ones(3) / np.sqrt(3)
    w = np.cross([0.0, 0.0, 1.0], axis)
    wx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    return d @ (np.eye(3) + wx + wx @ wx / (1 + axis[2])).T


def tint(albedo: np.ndarray, wall: str) -> np.ndarray:
    """Chroma towards a wall's colour: r - mean(g, b) for the red wall, b - mean(r, g) for the blue."""
    a = np.asarray(albedo, float)
    k = {"red": 0, "blue": 2}[wall]
    return a[..., k] - (a.sum(-1) - a[..., k]) / 2


def floor_strip(wall: str, n: int = 6) -> np.ndarray:
    """Points (n*n, 3) of the floor beside ``wall``: within 0.25 of it, away from the other wall."""
    near, along = np.linspace(0.03, 0.25, n), np.linspace(0.3, 0.9, n)
    a, b = (x.ravel() for x in np.meshgrid(near, along, indexing="ij"))
    return np.c_[a, b, np.zeros_like(a)] if wall == "red" else np.c_[b, a, np.zeros_like(a)]


def floor_tints(mesh: Mesh, cameras, reach: float = 0.15) -> dict:
    """The tint of ``mesh``'s albedo (its vertex colours) where the cameras see the floor beside
    each wall, less the true floor's tint (0: the floor is grey). Each camera casts a ray at
    every point of :func:`floor_strip`; hits within ``reach`` of the point count, their
    albedo interpolated from the hit face's vertices. {"red": t, "blue": t, "hits": {...}}."""
    caster = RayCaster(mesh)
    out = {"hits": {}}
    for wall in ("red", "blue"):
        values = []
        for cam in cameras:
            points = floor_strip(wall)
            d = points - cam.centre
            length = np.linalg.norm(d, axis=1)
            hits = caster.intersect(cam.centre, d / length[:, None])
            ok = hits.hit & (np.abs(hits.distance - length) < reach)
            if not ok.any():
                continue
            tri = mesh.faces[hits.face[ok]]
            corners = mesh.vertices[tri]
            # barycentric weights of the hit points in their faces
            e1, e2, p = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], hits.points[ok] - corners[:, 0]
            d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
            p1, p2 = (p * e1).sum(1), (p * e2).sum(1)
            den = np.maximum(d11 * d22 - d12 * d12, 1e-18)
            w1, w2 = (d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den
            w = np.clip(np.c_[1 - w1 - w2, w1, w2], 0, 1)
            w /= w.sum(1, keepdims=True)
            values.append((mesh.vertex_colors[tri] * w[..., None]).sum(1))
        albedo = np.concatenate(values) if values else np.zeros((0, 3))
        out["hits"][wall] = int(len(albedo))
        out[wall] = float(np.mean(tint(albedo, wall)) - tint(np.asarray(FLOOR), wall)) if len(albedo) else None
    return out


def write_open_corner(spec: CornerSpec, out: Path, emit=lambda *a, **k: None) -> Capture:
    """Render the corner capture into the empty folder ``out`` (the Mitsuba variant chosen)."""
    mesh, albedo, labels = corner_mesh(spec.cells)
    n = mesh.n_vertices
    specular, roughness = np.full(n, 1e-3, np.float32), np.full(n, 0.6, np.float32)
    material = VertexField(mesh.faces, albedo, specular, roughness)
    centre, radius = np.full(3, 0.5), float(np.sqrt(3) / 2)
    cams = layout.orbit_cameras(cap_directions(spec.views, spec.cone_deg), centre, radius, spec.resolution)
    lamp = PointLight(np.asarray(spec.lamp, float), np.full(3, float(spec.intensity)))
    lights = [[lamp] for _ in cams]
    settings = RenderSettings(spp=spec.spp, max_depth=spec.max_depth, integrator="path", hide_emitters=True)
    renderer = SceneRenderer(mesh, material, cams, lights, None, settings, rgba=True)
    frames = []
    for i, cam in enumerate(cams):
        rgba = renderer.render_numpy(i, seed=spec.seed * 1000 + i)
        image, mask = out / "images" / f"{i:04d}.exr", out / "masks" / f"{i:04d}.png"
        write_image(image, rgba[..., :3])
        write_mask(mask, rgba[..., 3])
        frames.append(Frame(f"{i:04d}", image, cam, mask=mask, lights=lights[i]))
        emit("progress", stage="synth:corner", iteration=i + 1, iterations=len(cams), fraction=(i + 1) / len(cams))
    truth = mesh.copy()
    truth.vertex_colors = albedo
    truth.attributes = {"specular": specular, "roughness": roughness, "label": labels.astype(np.float32)}
    save_mesh(out / "gt" / "mesh.ply", truth)
    fsio.write_json(out / "gt" / "material.json", {"albedo": {"floor": FLOOR, "red": RED, "blue": BLUE},
                                                  "specular": 1e-3, "roughness": 0.6, "model": "lambert+ggx",
                                                  "per_vertex": "gt/mesh.ply"})
    capture = Capture(out, frames, None)
    capture.ground_truth = {"mesh": "gt/mesh.ply", "material": "gt/material.json"}
    capture.provenance = {"source": "synth", "scene": "open corner", "spec": asdict(spec)}
    save_capture(capture)
    return capture
