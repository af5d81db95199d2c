"""Diffuse-only and specular-only renders (the paper's Table 1 splits PSNR/SSIM this way).

A component pass renders the same scene, lights and path depth with the other lobe switched
off in the material field: ``diffuse`` keeps the albedo and zeroes the specular reflectance,
``specular`` zeroes the albedo. Interreflections stay within the kept lobe, so the two passes
of the truth and of a reconstruction are compared like with like.

    images = component_renders(mesh, field, frames, environment, spp=256, max_depth=4)
    images["full"], images["diffuse"], images["specular"]     # lists of (H, W, 3) linear RGB
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from .scene import RenderSettings, SceneRenderer

COMPONENTS = ("full", "diffuse", "specular")


class ComponentField:
    """A material field with one lobe switched off: ``keep`` is "diffuse" or "specular"."""

    def __init__(self, field, keep: str):
        if keep not in ("diffuse", "specular"):
            raise ValueError(f"keep must be 'diffuse' or 'specular', not {keep!r}")
        self.inner, self.keep = field, keep

    def arrays(self) -> dict:
        return self.inner.arrays()

    def lookup(self, si, active):
        albedo, specular, roughness = self.inner.lookup(si, active)
        if self.keep == "diffuse":
            return albedo, mi.Float(0.0), roughness
        return mi.Color3f(0.0), specular, roughness


def component_renders(mesh, field, frames, environment=None, spp: int = 64, max_depth: int = 4,
                      seed: int = 900, components=COMPONENTS, env_pixels: np.ndarray | None = None) -> dict:
    """Renders of ``mesh`` with ``field`` at ``frames`` (their cameras and point lights, plus
    ``environment``) for each component: {component: [(H, W, 3) linear RGB per frame]}."""
    renderer = SceneRenderer(mesh, field, [f.camera for f in frames], [f.lights for f in frames], environment,
                             RenderSettings(spp=spp, max_depth=max_depth, integrator="path"), env_pixels=env_pixels)
    out = {}
    for name in components:
        renderer.set_field(field if name == "full" else ComponentField(field, name))
        out[name] = [renderer.render_numpy(v, seed=seed + v)[..., :3] for v in range(len(frames))]
    renderer.set_field(field)
    return out
