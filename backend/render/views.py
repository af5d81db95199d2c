"""Render a reconstruction's display mesh (per-vertex albedo, specular, roughness) at the
cameras of a capture, under that capture's lights: novel-view and relit evaluation."""

from __future__ import annotations

import numpy as np

from ..capture.model import Capture
from ..geometry.mesh import Mesh
from ..material.base import NEUTRAL
from .fields import VertexField
from .scene import RenderSettings, SceneRenderer


def display_field(mesh: Mesh) -> VertexField:
    """The material a display mesh carries (neutral grey where a channel is absent)."""
    n = mesh.n_vertices
    albedo = mesh.vertex_colors if mesh.vertex_colors is not None else np.full((n, 3), NEUTRAL["albedo"])
    channel = {k: mesh.attributes.get(k, np.full(n, NEUTRAL[k])) for k in ("specular", "roughness")}
    return VertexField(mesh.faces, albedo, channel["specular"], channel["roughness"])


def render_views(mesh: Mesh, capture: Capture, spp: int = 64, max_depth: int = 4, seed: int = 0) -> dict[str, np.ndarray]:
    """Linear RGB renders of ``mesh`` for every frame of ``capture``, keyed by frame name."""
    frames = capture.frames
    renderer = SceneRenderer(mesh, display_field(mesh), [f.camera for f in frames], [f.lights for f in frames],
                             capture.environment, RenderSettings(spp=spp, max_depth=max_depth, integrator="path"))
    return {f.name: renderer.render_numpy(i, seed=seed + i)[..., :3] for i, f in enumerate(frames)}
