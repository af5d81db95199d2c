"""Render a synthetic capture with ground truth (mesh, material, held-out and relit views).

:func:`write_synthetic_capture` is the ``synth`` command's job; :func:`synthesize` renders
into a folder the caller provides."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import mitsuba as mi
import numpy as np

from .. import __version__, fsio, variant
from ..capture.format import save_capture
from ..capture.images import read_rgba, write_image, write_mask
from ..capture.model import Camera, Capture, Environment, Frame
from ..geometry.mesh import Mesh, load_mesh, save_mesh
from ..render.fields import VertexField
from ..render.scene import RenderSettings, SceneRenderer
from ..lighting.exposure import AUTO_FLAG
from . import drift, layout, procedural

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])


@dataclass
class SynthSpec:
    """Everything that defines a synthetic capture (stored in its provenance)."""

    mesh: str = "blob"  # a mesh file, or "blob" for the built-in procedural object
    up: str = "z"  # the mesh file's up axis (y meshes are rotated to Z up)
    views: int = 16
    resolution: int = 128
    lighting: str = "points"  # "points" (paper layout: 2 per camera), "flash" (1 at each camera) or "env"
    environment: str = "sky"  # an HDR file, or "sky" for the procedural sky
    env_strength: float = 1.0
    env_rotation_deg: float = 0.0
    light_intensity: float = 0.0  # W/sr per point light; 0 = automatic from the distance
    cornell: bool = False
    albedo: list[float] | str = "pattern"  # RGB constant or "pattern"
    specular: float = 0.25
    roughness: float = 0.35
    spp: int = 64
    max_depth: int = 4
    held_out: int = 4
    relit_environment: str = "sky2"  # "sky2" = a second procedural sky; or an HDR file
    exposure_drift: float = 0.0  # stops: a phone's auto-exposure swing over the frames (backend.synth.drift)
    white_balance_drift: float = 0.0  # stops: its white-balance drift (temperature and tint)
    image_format: str = "exr"  # exr (linear) or png (8-bit sRGB)
    seed: int = 0


def load_spec_mesh(spec: SynthSpec) -> Mesh:
    if spec.mesh == "blob":
        return procedural.blob()
    mesh = load_mesh(spec.mesh)
    return mesh.transformed(Y_UP_TO_Z_UP) if spec.up == "y" else mesh


def vertex_material(spec: SynthSpec, mesh: Mesh):
    if spec.albedo == "pattern":
        albedo = procedural.albedo_pattern(mesh.vertices)
    else:
        albedo = np.tile(np.asarray(spec.albedo, np.float32), (mesh.n_vertices, 1))
    spec_v = np.full(mesh.n_vertices, spec.specular, np.float32)
    rough_v = np.full(mesh.n_vertices, spec.roughness, np.float32)
    return albedo, spec_v, rough_v


def _environment_pixels(name: str, which: int) -> np.ndarray:
    if name in ("sky", "sky2"):
        if which == 0:
            return procedural.sky(256, 35, 40, 400)
        return procedural.sky(256, 60, -120, 250)
    return read_rgba(name)[0][..., :3]


def cornell_shapes(centre: np.ndarray, half: float) -> dict:
    """A room around the cameras: red wall at -x, green at +x, white elsewhere."""

    def wall(name, normal, colour):
        n = np.asarray(normal, float)
        to_world = layout.look_at(centre - n * half, centre)  # rectangle faces +z -> toward centre
        to_world = to_world @ np.diag([half, half, 1.0, 1.0])
        flip = np.diag([1.0, 1.0, -1.0, 1.0])  # rectangle normal is +z; look_at's z points back
        return name, {"type": "rectangle", "to_world": mi.ScalarTransform4f(to_world @ flip),
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": colour}}}

    walls = [wall("wall_left", [-1, 0, 0], [0.63, 0.06, 0.04]), wall("wall_right", [1, 0, 0], [0.14, 0.45, 0.09]),
             wall("wall_back", [0, 1, 0], [0.72, 0.72, 0.72]), wall("wall_front", [0, -1, 0], [0.72, 0.72, 0.72]),
             wall("floor", [0, 0, -1], [0.72, 0.72, 0.72]), wall("ceiling", [0, 0, 1], [0.72, 0.72, 0.72])]
    return dict(walls)


def _write_view_set(root: Path, renderer, masker, cameras: list[Camera], lights, names: list[str],
                    spec: SynthSpec, environment: Environment | None, emit, what: str,
                    gains: np.ndarray | None = None) -> Capture:
    """Render and write one set of views; ``gains`` (N, 3): each frame's camera response."""
    frames = []
    for i, (cam, name) in enumerate(zip(cameras, names)):
        rgba = renderer.render_numpy(i, seed=spec.seed * 1000 + i)
        if gains is not None:
            rgba[..., :3] *= gains[i].astype(rgba.dtype)
        if masker is not None:  # the room covers every pixel: mask the object alone
            rgba[..., 3] = masker.render_numpy(i, seed=i)[..., 3]
        image = root / "images" / f"{name}.{spec.image_format}"
        mask = root / "masks" / f"{name}.png"
        write_image(image, rgba[..., :3])
        write_mask(mask, rgba[..., 3])
        frames.append(Frame(name, image, cam, mask=mask, lights=lights[i]))
        emit("progress", stage=f"synth:{what}", iteration=i + 1, iterations=len(cameras),
             fraction=(i + 1) / len(cameras))
    return Capture(root, frames, environment)


def synthesize(spec: SynthSpec, out: Path, emit) -> Capture:
    """Render the capture into ``out`` (an empty folder; the caller makes it atomic)."""
    mesh = load_spec_mesh(spec)
    lo, hi = mesh.bounds()
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    albedo, spec_v, rough_v = vertex_material(spec, mesh)
    field = VertexField(mesh.faces, albedo, spec_v, rough_v)

    held_offset = 0.5 / max(spec.held_out, 1)  # a different spiral from the training views
    cams = layout.orbit_cameras(layout.fibonacci_sphere(spec.views), centre, radius, spec.resolution)
    held = layout.orbit_cameras(layout.fibonacci_sphere(spec.held_out, held_offset), centre, radius,
                                spec.resolution) if spec.held_out else []
    distance = float(np.linalg.norm(cams[0].centre - centre))
    intensity = spec.light_intensity or 0.6 * distance ** 2

    env = env_pixels = None
    if spec.lighting == "env":
        env_pixels = _environment_pixels(spec.environment, 0)
        env = Environment(out / "env.exr", spec.env_strength, spec.env_rotation_deg)
        write_image(env.path, env_pixels)
    lights_of = {"points": lambda c: layout.paper_lights(c, intensity),
                 "flash": lambda c: layout.flash_light(c, intensity)}.get(spec.lighting, lambda c: [])
    extra = cornell_shapes(centre, 2.5 * distance) if spec.cornell else None
    settings = RenderSettings(spp=spec.spp, max_depth=spec.max_depth, integrator="path",
                              hide_emitters=True)

    def render_set(root, cameras, names, what, environment, pixels, point_lights=True, gains=None):
        lights = [lights_of(c) if point_lights else [] for c in cameras]
        renderer = SceneRenderer(mesh, field, cameras, lights, environment, settings, extra, pixels, rgba=True)
        masker = SceneRenderer(mesh, field, cameras, lights, None, RenderSettings(spp=16, max_depth=2),
                               rgba=True) if extra else None
        return _write_view_set(root, renderer, masker, cameras, lights, names, spec, environment, emit, what, gains)

    # the training frames only: held-out and relit views are the truth, at the gauge's gain 1
    drifting = bool(spec.exposure_drift or spec.white_balance_drift)
    gains = drift.drift_gains(len(cams), spec.exposure_drift, spec.white_balance_drift, spec.seed) if drifting else None
    names = [f"{i:04d}" for i in range(len(cams))]
    capture = render_set(out, cams, names, "train", env, env_pixels, gains=gains)
    gt = out / "gt"
    gt_mesh = mesh.copy()
    gt_mesh.vertex_colors = albedo
    gt_mesh.attributes = {"specular": spec_v, "roughness": rough_v}
    save_mesh(gt / "mesh.ply", gt_mesh)
    material = {"albedo": spec.albedo, "specular": spec.specular, "roughness": spec.roughness,
                "model": "lambert+ggx", "per_vertex": "gt/mesh.ply"}
    fsio.write_json(gt / "material.json", material)
    truth = {"mesh": "gt/mesh.ply", "material": "gt/material.json"}
    if drifting:
        fsio.write_json(gt / "exposure.json", drift.truth(names, gains, spec.exposure_drift, spec.white_balance_drift))
        truth["exposure"] = "gt/exposure.json"
    if held:
        names = [f"held{i:02d}" for i in range(len(held))]
        held_env = env and Environment(gt / "held_out" / "env.exr", env.strength, env.rotation_z_deg)
        sub = render_set(gt / "held_out", held, names, "held_out", held_env, env_pixels)
        if env is not None:
            write_image(sub.environment.path, env_pixels)
        save_capture(sub)
        relit_pixels = _environment_pixels(spec.relit_environment, 1)
        relit_env = Environment(gt / "relit" / "env.exr", 1.0, 0.0)
        write_image(relit_env.path, relit_pixels)
        sub = render_set(gt / "relit", held, names, "relit", relit_env, relit_pixels, point_lights=False)
        save_capture(sub)
        truth.update(held_out="gt/held_out", relit="gt/relit")
    capture.ground_truth = truth
    capture.provenance = {"source": "synth", "tool": f"shape-from-tracing {__version__}",
                          "spec": json.loads(json.dumps(asdict(spec)))}
    if drifting:  # each frame exposed and white-balanced on its own, as a phone's: --exposure auto fits them
        capture.provenance[AUTO_FLAG] = True
    if spec.cornell:
        capture.provenance["scene"] = {"cornell": {"centre": centre.tolist(), "half": 2.5 * distance}}
    save_capture(capture)
    return capture


def write_synthetic_capture(spec: SynthSpec, out: Path, emit, overwrite: bool = False,
                            variant_name: str | None = None) -> Capture:
    """Choose the Mitsuba variant and render ``spec`` into the new folder ``out``, which
    appears only once complete; ends with a ``done`` event."""
    variant.choose(variant_name, emit)
    with fsio.atomic_dir(out, replace=overwrite) as tmp:
        capture = synthesize(spec, tmp, emit)
    emit("done", capture=str(out), frames=len(capture.frames))
    return capture
