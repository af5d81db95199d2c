"""Mitsuba scenes for a capture: one object mesh, its cameras and its lights.

Conventions are exact translations of the capture model (docs/capture-format.md):
Mitsuba cameras look along +z with x to the left, so ``to_world = camera_to_world @
diag(-1, 1, -1, 1)``; Mitsuba's principal-point offset is the negated offset of (cx, cy)
from the image centre in units of the image size; the environment map's Blender lookup
is an axis permutation of Mitsuba's, so it needs no resampling."""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..capture.images import read_rgba
from ..capture.model import Camera, Environment, PointLight
from ..capture.undistort import needs_resampling
from ..geometry.mesh import Mesh
from ..geometry.raycast import mitsuba_mesh  # noqa: F401  (re-exported: render.scene.mitsuba_mesh)
from ..lighting.summed_map import SummedMaps
from . import bsdf as _bsdf  # noqa: F401  (registers sft_surface)
from . import projective as _projective  # noqa: F401  (registers sft_direct_projective, sft_prb_projective)

GL_TO_MITSUBA_CAMERA = np.diag([-1.0, 1.0, -1.0, 1.0])
# Mitsuba envmap local axes (x, y, z) <- Blender lookup axes (y', z', x').
_ENV_PERMUTATION = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

INTEGRATORS = ("path", "prb", "direct", "direct_projective", "prb_projective")


@dataclass
class RenderSettings:
    """How to render. ``max_depth`` counts path vertices as Mitsuba does: 2 = direct light only."""

    spp: int = 16
    max_depth: int = 3
    integrator: str = "path"
    hide_emitters: bool = True  # camera rays that miss the object see black
    sppc: int = 0  # projective integrators: continuous part uses spp
    # projective gradient renders (mi.render with spp=0): samples of the primal image, the
    # sensors' own count; the backward pass keeps sppc / sppp / sppi (0: spp)
    primal_spp: int = 0
    sppp: int = 4  # primary-visibility (silhouette) samples per pixel
    sppi: int = 0  # indirect-visibility samples; 0 unless shadows change with the geometry
    # guiding of the indirect-visibility samples ('none' | 'grid' | 'octree', Mitsuba's default):
    # Mitsuba rebuilds a grid or octree in every backward pass, per view, for less accuracy per
    # second than unguided samples (docs/notes/2026-11-24-hdr-shadow-gradients.md)
    guiding: str = "none"
    rr_depth: int = 100

    @classmethod
    def for_geometry(cls, config) -> "RenderSettings":
        """A run's geometry steps before its effects decision: the ``config``'s samples, depth
        and integrator (a ReconstructConfig), emitters hidden, no shadow gradients."""
        return cls(spp=config.spp, max_depth=config.max_depth, integrator=config.integrator, hide_emitters=True,
                   sppc=config.spp, sppp=config.sppp, sppi=0, primal_spp=config.primal_spp)

    def integrator_dict(self) -> dict:
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"unknown integrator {self.integrator}")
        d = {"type": self.integrator, "hide_emitters": self.hide_emitters}
        if self.integrator == "direct":
            d = {"type": "direct", "hide_emitters": self.hide_emitters}
            return d
        if self.integrator != "direct_projective":
            d["max_depth"] = self.max_depth
            d["rr_depth"] = self.rr_depth
        if self.integrator.endswith("projective"):
            # the plugin with the cheaper silhouette terms (render.projective), same estimates
            d.update(type=f"sft_{self.integrator}", sppc=self.sppc or self.spp, sppp=self.sppp, sppi=self.sppi)
            if self.sppi > 0:
                d["guiding"] = self.guiding
        return d


def sensor_dict(camera: Camera, spp: int, rgba: bool = False) -> dict:
    if needs_resampling(camera):
        raise ValueError("distorted or non-square pixels: import the capture (undistorts) first")
    w, h = camera.width, camera.height
    return {
        "type": "perspective",
        "fov": float(np.degrees(2 * np.arctan(w / (2 * camera.fx)))),
        "fov_axis": "x",
        "principal_point_offset_x": -(camera.cx - w / 2) / w,
        "principal_point_offset_y": -(camera.cy - h / 2) / h,
        "near_clip": 1e-3,
        "to_world": mi.ScalarTransform4f(camera.camera_to_world @ GL_TO_MITSUBA_CAMERA),
        "film": {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"},
                 "pixel_format": "rgba" if rgba else "rgb", "sample_border": True},
        "sampler": {"type": "independent", "sample_count": spp},
    }


def environment_to_world(rotation_z_deg: float) -> np.ndarray:
    a = np.radians(rotation_z_deg)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    m = np.eye(4)
    m[:3, :3] = rz.T @ _ENV_PERMUTATION.T
    return m


def rig_environment_to_world(env: Environment, camera: Camera) -> np.ndarray:
    """A camera-fixed map's transform for one view (``Environment.frame`` "camera"): the
    lookup takes the rig frame's direction, d_rig = A^T d, with A = ``Environment.rig_axes``,
    so to_world = A x the world map's transform."""
    m = np.eye(4)
    m[:3, :3] = Environment.rig_axes(camera.camera_to_world)
    return m @ environment_to_world(env.rotation_z_deg)


def environment_dict(env: Environment, pixels: np.ndarray | None = None) -> dict:
    if pixels is None:
        pixels = env.pixels if env.pixels is not None else read_rgba(env.path)[0][..., :3]
    return {"type": "envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(pixels, dtype=np.float32)),
            "scale": float(env.strength),
            "to_world": mi.ScalarTransform4f(environment_to_world(env.rotation_z_deg))}


def point_light_dict(light: PointLight) -> dict:
    return {"type": "point", "position": [float(x) for x in light.position],
            "intensity": {"type": "rgb", "value": [float(x) for x in light.intensity]}}


class SceneRenderer:
    """Renders one object mesh from a capture's views under their lights.

    Per-view point lights are set before each render (the scene holds as many point
    emitters as the frame with the most lights; unused ones get zero intensity), times the
    ``light_scale`` a fit sets (``set_light_scale``)."""

    def __init__(self, mesh: Mesh, field, cameras: list[Camera], lights: list[list[PointLight]],
                 environment: Environment | None = None, settings: RenderSettings | None = None,
                 extra_shapes: dict | None = None, env_pixels: np.ndarray | None = None,
                 rgba: bool = False):
        self.settings = settings or RenderSettings()
        self.cameras = cameras
        self.lights = lights
        self.bsdf = _bsdf.SurfaceBSDF(mi.Properties(), field)
        self.field = field
        self.object = mitsuba_mesh(mesh, self.bsdf)
        scene = {"type": "scene", "integrator": self.settings.integrator_dict(), "object": self.object}
        self.n_lights = max((len(ls) for ls in lights), default=0)
        for k in range(self.n_lights):
            scene[f"light{k}"] = point_light_dict(PointLight(np.zeros(3), np.zeros(3)))
        if environment is not None:
            scene["environment"] = environment_dict(environment, env_pixels)
        # a camera-fixed map turns with each view (set before each render, as the point lights)
        self.rig = ([rig_environment_to_world(environment, c) for c in cameras]
                    if environment is not None and environment.frame == "camera" else None)
        self._rig_view = None
        # a summed world + camera map: the envmap is set to their sum before each render
        self.summed = None
        if environment is not None and environment.frame == "world+camera":
            self.summed = SummedMaps(environment, cameras, env_pixels)
        scene.update(extra_shapes or {})
        self.scene = mi.load_dict(scene)
        self.params = mi.traverse(self.scene)
        # the sensors' count is what a render at spp=0 uses (GradientRenderer.render_split)
        primal = self.settings.primal_spp if self.settings.integrator.endswith("projective") else 0
        self.sensors = [mi.load_dict(sensor_dict(c, primal or self.settings.spp, rgba)) for c in cameras]
        self._light_view = None
        self.light_scale = None  # a Dr.Jit Color3f times every point light's intensity (a fitted flash)

    @property
    def vertex_key(self) -> str:
        return "object.vertex_positions"

    def set_mesh(self, mesh: Mesh) -> None:
        self.params["object.vertex_positions"] = mi.Float(mesh.vertices.astype(np.float32).ravel())
        self.params["object.faces"] = mi.UInt32(mesh.faces.astype(np.uint32).ravel())
        self.params.update()

    def set_field(self, field) -> None:
        """Swap the material field; parameters are re-traversed to expose its arrays."""
        self.field = field
        self.bsdf.field = field
        self.params = mi.traverse(self.scene)

    def set_light_scale(self, scale) -> None:
        """Every point light's intensity times ``scale`` (a Dr.Jit Color3f, possibly attached to
        AD: an intensity being fitted) from the next render on; None: the lights as given
        (re-read, so lights changed in place show)."""
        self.light_scale = scale
        self._light_view = None

    def _set_lights(self, view: int) -> None:
        # a scale attached to AD is set again for every render: a backward pass uses up its graph
        if (self._light_view == view and self.light_scale is None) or self.n_lights == 0:
            return
        lights = self.lights[view]
        for k in range(self.n_lights):
            light = lights[k] if k < len(lights) else PointLight(np.zeros(3), np.zeros(3))
            pos = mi.Point3f(*map(float, light.position))
            val = mi.Color3f(*map(float, light.intensity))
            dr.make_opaque(pos, val)
            self.params[f"light{k}.position"] = pos
            self.params[f"light{k}.intensity.value"] = val if self.light_scale is None else val * self.light_scale
        self.params.update()
        self._light_view = view

    def _set_rig(self, view: int) -> None:
        if self.rig is None or self._rig_view == view:
            return
        self.params["environment.to_world"] = mi.ScalarTransform4f(self.rig[view])
        self.params.update()
        self._rig_view = view

    def render(self, view: int, seed: int = 0, spp: int | None = None, params=None):
        """Render one view: an (H, W, 3) Dr.Jit tensor, (H, W, 4) with coverage as alpha
        when built with ``rgba``; differentiable w.r.t. ``params``."""
        self._set_lights(view)
        self._set_rig(view)
        if self.summed is not None:
            self.summed.write(self, view, params)
        return mi.render(self.scene, params if params is not None else self.params,
                         sensor=self.sensors[view], seed=seed, spp=spp or self.settings.spp)

    def render_numpy(self, view: int, seed: int = 0, spp: int | None = None) -> np.ndarray:
        with dr.suspend_grad():
            return np.array(self.render(view, seed, spp))
