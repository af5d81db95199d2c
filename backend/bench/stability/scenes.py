"""The synthetic captures and initial meshes of the stability cases, each with one hard
property (grazing views, near-black frames, NaN pixels, a 1e5 sun, degenerate or tangled meshes)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ... import variant
from ...capture.format import save_capture
from ...capture.images import write_image, write_mask
from ...capture.model import Camera, Capture, Environment, Frame, PointLight
from ...geometry.mesh import Mesh
from ...material.model import MeshColorMaterial
from ...render.fields import ConstantField
from ...render.scene import RenderSettings, SceneRenderer
from ...synth.layout import fibonacci_sphere, look_at, orbit_cameras
from ...synth.procedural import blob, icosphere
from .._scenes import torus


@dataclass
class Scene:
    """A synthetic capture to build: object, views, lights and material of the truth."""

    mesh: object  # backend.geometry.mesh.Mesh
    cameras: list
    lights: list  # per view: list of PointLight
    albedo: float | list = 0.6
    specular: float = 0.2
    roughness: float = 0.4
    env_pixels: np.ndarray | None = None
    spp: int = 16
    edit: Callable | None = None  # (view index, rgb, alpha) -> (rgb, alpha): post-processing

    def write(self, out: Path) -> Path:
        """Render the capture into ``out`` (images, masks, capture.json; no ground truth, so the
        loop spends no time on metrics)."""
        variant.choose()
        out = Path(out)
        env = None
        if self.env_pixels is not None:
            env = Environment(out / "env.exr")
            write_image(env.path, self.env_pixels)
        renderer = SceneRenderer(self.mesh, ConstantField(self.albedo, self.specular, self.roughness), self.cameras,
                                 self.lights, env, RenderSettings(spp=self.spp, max_depth=3, integrator="path"),
                                 env_pixels=self.env_pixels, rgba=True)
        frames = []
        for i, cam in enumerate(self.cameras):
            rgba = renderer.render_numpy(i, seed=i)
            rgb, alpha = rgba[..., :3], rgba[..., 3]
            if self.edit is not None:
                rgb, alpha = self.edit(i, rgb, alpha)
            image, mask = out / "images" / f"{i:04d}.exr", out / "masks" / f"{i:04d}.png"
            write_image(image, rgb)
            write_mask(mask, alpha)
            frames.append(Frame(f"{i:04d}", image, cam, mask=mask, lights=self.lights[i]))
        save_capture(Capture(out, frames, env, provenance={"source": "bench stability"}))
        return out


def size_of(quick: bool) -> int:
    return 32 if quick else 64


def orbit(n: int, size: int, radius: float = 0.6):
    return orbit_cameras(fibonacci_sphere(n), np.zeros(3), radius, size)


def lamp_lights(cameras, power: float = 2.0):
    return [[PointLight(c.centre, np.full(3, power))] for c in cameras]


def lit_blob(quick: bool, views: int = 6, **material) -> Scene:
    """The procedural blob (about 1.1 units across) seen from ``views`` cameras around it, a
    lamp at each camera."""
    cams = orbit(views, size_of(quick))
    return Scene(blob(3 if quick else 4), cams, lamp_lights(cams), **material)


def grazing_scene(quick: bool) -> Scene:
    """A flat disc seen only from 2 to 6 degrees above its plane."""
    size = size_of(quick)
    disc = icosphere(3 if quick else 4, 0.6)
    disc.vertices[:, 2] *= 0.12
    f = 0.5 * size / np.tan(np.radians(20))
    cams = []
    for k, az in enumerate(np.linspace(0, 2 * np.pi, 6, endpoint=False)):
        el = np.radians(2 + 4 * (k % 2))
        eye = 2.0 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(Camera(size, size, f, f, size / 2, size / 2, look_at(eye, np.zeros(3))))
    return Scene(disc, cams, lamp_lights(cams))


def masked_out_scene(quick: bool) -> Scene:
    """Six views: two look away from the object (empty frames and masks), one sees it with
    image and mask blanked (the object masked out where it stands)."""
    scene = lit_blob(quick)
    for i in (1, 3):
        cam = scene.cameras[i]
        cam.camera_to_world = look_at(cam.centre, 2 * cam.centre)
    scene.edit = lambda i, rgb, alpha: (rgb * 0, alpha * 0) if i == 4 else (rgb, alpha)
    return scene


def near_black_scene(quick: bool) -> Scene:
    """Frames at 1e-4 of the exposure (a frame with no signal at all is bad input: the capture's
    validation names it)."""
    scene = lit_blob(quick)
    scene.edit = lambda i, rgb, alpha: (rgb * 1e-4, alpha)
    return scene


def nonfinite_pixel_scene(quick: bool) -> Scene:
    """One frame with a NaN and an Inf pixel on the object (a corrupt or clipped HDR frame)."""
    scene = lit_blob(quick)

    def corrupt(i, rgb, alpha):
        if i == 2:
            h, w = alpha.shape
            rgb = rgb.copy()
            rgb[h // 2, w // 2], rgb[h // 2 + 1, w // 2] = np.nan, np.inf
        return rgb, alpha

    scene.edit = corrupt
    return scene


def sun_scene(quick: bool) -> Scene:
    """Lit by an HDR map alone: a 2x2-pixel sun of radiance 1e5 beside a sky of 0.02; glossy."""
    sky = np.full((32, 64, 3), 0.02, np.float32)
    sky[6:8, 20:22] = 1e5
    scene = lit_blob(quick, specular=0.5, roughness=0.1)
    scene.lights = [[] for _ in scene.cameras]
    scene.env_pixels, scene.spp = sky, 4
    return scene


def degenerate_init(quick: bool):
    """A sphere around the object with flipped faces, duplicate vertices, zero-area and sliver
    triangles, a stray triangle through the inside and a non-manifold edge (a fin)."""
    sphere = icosphere(3, 0.7)
    v, f = sphere.vertices, sphere.faces.copy()
    f[::9] = f[::9, ::-1]
    n = len(v)
    a, b = f[0, 0], f[0, 1]
    v = np.vstack([v, v[:3], v[0] + [1e-9, 0, 0], 1.3 * v[a] + [0, 0.05, 0], 1.3 * v[b]])
    extra = [[0, n, 0], [1, 1, 2],  # zero-area (a duplicate vertex) and collapsed
             [n + 1, n + 2, n + 3],  # a stray triangle through the inside
             [0, 1, n + 3],  # a sliver
             [a, b, n + 4], [b, a, n + 5]]  # a fin: third and fourth face on one edge
    return Mesh(v, np.vstack([f, extra]))


def tangled_init(quick: bool):
    """A sphere after an oversized step: a cap of vertices pushed 1.6 radii down through the
    opposite side, so the surface intersects itself."""
    mesh = icosphere(3, 0.7)
    cap = mesh.vertices[:, 2] > 0.35
    mesh.vertices[cap, 2] -= 1.6 * 0.7
    return mesh


def swallowing_init(quick: bool):
    """A sphere over the object that also swallows the first camera (a mesh in the wrong place
    or units), while the other cameras still see it."""
    eye = orbit(6, size_of(quick))[0].centre
    mesh = icosphere(3, 0.6 * np.linalg.norm(eye))
    mesh.vertices += 0.5 * eye
    return mesh


def sphere_init(radius: float, subdivisions: int = 3):
    def build(quick: bool):
        return icosphere(subdivisions, radius)

    return build


def torus_init(faces: int):
    """A torus of about ``faces`` faces around the object."""
    def build(quick: bool):
        n_minor = max(8, int(round(np.sqrt(faces / 5))))
        return torus(0.45, 0.25, max(8, int(round(faces / 2 / n_minor))), n_minor)

    return build


def meshcolors(resolution: int):
    """Mesh colors at ``resolution`` on the initial mesh, every channel spatial and estimated."""
    def build(mesh):
        material = MeshColorMaterial(mesh, resolution)
        for name in material.CHANNELS:
            material.make_spatial(name)
        return material

    return build
