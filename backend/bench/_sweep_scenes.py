"""The sweep's benchmark scenes: synthetic captures with ground truth, built once and cached.

- ``dragon``: the paper's setting, the dragon under two point lights per camera (constant
  glossy material, which the reconstruction estimates);
- ``blob_env``: the built-in convex-ish blob with a textured albedo under an HDR map;
- ``corner``: a solid three-plane corner (a cube with a cube cut out of one corner) with a
  red, a blue and a white plane, lit from the cameras: strong colour bleeding inside;
- ``armadillo_env``: the Stanford armadillo under the forest HDR map, which shades itself in
  its armpits, between its legs and behind its ears (shadow gradients matter);
- ``video``: the video path: a Cycles orbit video of Spot under the sunset map, with no
  poses, through ``capture-from-video`` (SfM); the truth is carried into the capture's frame;
- ``tiny``: the blob at 32 px, for the smoke test.

Every capture but ``video`` has held-out views and relit views (under a second sky) in
``gt/``; the video's frames are all the video gives, so its runs have F1 and Chamfer only."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .. import fsio
from ..capture.format import save_capture
from ..capture.images import write_image, write_mask
from ..capture.model import Capture, Environment, Frame
from ..capture.load import load_capture
from ..geometry.mesh import Mesh, load_mesh, save_mesh
from ..metrics.geometry import align_similarity
from ..render.fields import VertexField
from ..render.scene import RenderSettings, SceneRenderer
from ..synth import layout, procedural
from ..synth.capture import SynthSpec, synthesize
from . import _launch, realworld
from ._data import SHARED_DATA as SHARED

DRAGON = SHARED / "meshes" / "shapefromtracing" / "dragon.obj"  # Y up (standing along +Y)
ARMADILLO = SHARED / "meshes" / "stanford" / "armadillo_86k.obj"  # Y up
STUDIO = SHARED / "envmaps" / "studio_small_03_1k.hdr"
FOREST = SHARED / "envmaps" / "forest_slope_1k.hdr"
# the armadillo scene, as synth options (tests build it smaller with the same options otherwise)
ARMADILLO_ENV = dict(mesh=str(ARMADILLO), up="y", views=32, resolution=128, lighting="env", environment=str(FOREST),
                     albedo=[0.6, 0.6, 0.6], specular=0.2, roughness=0.4, spp=256, max_depth=4, held_out=4)
CORNER_COLOURS = {"floor": [0.75, 0.75, 0.75], "x": [0.75, 0.08, 0.06], "y": [0.08, 0.12, 0.75]}


@dataclass
class Scene:
    name: str
    description: str
    build: Callable[[Path, Callable], None]  # (empty folder, emit) -> writes the capture there


def _synth(**values) -> Callable[[Path, Callable], None]:
    def build(out: Path, emit) -> None:
        synthesize(SynthSpec(**values), out, emit)
    return build


def _studio() -> str:
    return str(STUDIO) if STUDIO.is_file() else "sky"


def voxel_surface(occupied: np.ndarray, lo, spacing: float) -> Mesh:
    """The closed, outward-wound boundary of a set of voxels (True = solid) as triangles.

    Voxel (i, j, k) spans ``lo + spacing * [i, i+1] x [j, j+1] x [k, k+1]``; boundary faces
    between a solid and an empty voxel become two triangles on the shared grid nodes."""
    occ = np.pad(np.asarray(occupied, bool), 1)
    n = np.array(occupied.shape) + 1  # nodes per axis
    quads, normals = [], []
    for a in range(3):
        b, c = [x for x in range(3) if x != a]
        o = np.moveaxis(occ, a, 0)
        for mask, sign in ((o[:-1] & ~o[1:], 1.0), (~o[:-1] & o[1:], -1.0)):
            m, u, v = np.nonzero(mask)  # plane at node m along a; cell (u-1, v-1) along b, c
            u, v = u - 1, v - 1
            corners = []
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                idx = np.zeros((len(m), 3), int)
                idx[:, a], idx[:, b], idx[:, c] = m, u + du, v + dv
                corners.append(idx[:, 0] * n[1] * n[2] + idx[:, 1] * n[2] + idx[:, 2])
            quads.append(np.stack(corners, 1))
            normal = np.zeros(3)
            normal[a] = sign
            normals.append(np.tile(normal, (len(m), 1)))
    quads, normals = np.concatenate(quads), np.concatenate(normals)
    used, inverse = np.unique(quads, return_inverse=True)
    quads = inverse.reshape(quads.shape)
    ijk = np.stack(np.unravel_index(used, tuple(n)), 1)
    vertices = np.asarray(lo, float) + spacing * ijk
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    e1 = vertices[faces[:, 1]] - vertices[faces[:, 0]]
    e2 = vertices[faces[:, 2]] - vertices[faces[:, 0]]
    flip = (np.cross(e1, e2) * np.concatenate([normals, normals])).sum(1) < 0
    faces[flip] = faces[flip][:, ::-1]
    return Mesh(vertices, faces)


def corner_mesh(cells: int = 20, thickness: int = 3) -> tuple[Mesh, np.ndarray]:
    """The corner solid in [-0.5, 0.5]^3 (open towards +x +y +z) and its per-vertex albedo:
    the floor slab (low z) white, the slab at low x red, the one at low y blue."""
    i, j, k = np.meshgrid(*[np.arange(cells)] * 3, indexing="ij")
    mesh = voxel_surface((i < thickness) | (j < thickness) | (k < thickness), [-0.5] * 3, 1.0 / cells)
    inner = -0.5 + thickness / cells + 1e-9
    x, y, z = mesh.vertices.T
    albedo = np.where((z <= inner)[:, None], CORNER_COLOURS["floor"],
                      np.where((x <= inner)[:, None], CORNER_COLOURS["x"], CORNER_COLOURS["y"]))
    return mesh, albedo.astype(np.float32)


def _corner_directions(n: int, offset: float = 0.0) -> np.ndarray:
    """``n`` view directions all around (the outside needs silhouettes too), the spiral's
    +z pole turned onto the corner's open diagonal."""
    d = layout.fibonacci_sphere(n, offset)
    axis = np.ones(3) / np.sqrt(3)  # rotate +z onto the corner's open diagonal
    v = np.cross([0.0, 0.0, 1.0], axis)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    rot = np.eye(3) + vx + vx @ vx / (1 + axis[2])
    return d @ rot.T


def _write_views(root: Path, renderer, cameras, lights, names, seed: int):
    frames = []
    for i, (cam, name) in enumerate(zip(cameras, names)):
        rgba = renderer.render_numpy(i, seed=seed * 1000 + i)
        image, mask = root / "images" / f"{name}.exr", root / "masks" / f"{name}.png"
        write_image(image, rgba[..., :3])
        write_mask(mask, rgba[..., 3])
        frames.append(Frame(name, image, cam, mask=mask, lights=lights[i]))
    return frames


def build_corner(out: Path, emit, views: int = 24, held_out: int = 4, resolution: int = 128, spp: int = 256,
                 max_depth: int = 8, specular: float = 0.05, roughness: float = 0.5, seed: int = 0) -> None:
    """The corner capture: training views under camera-mounted point lights (the paper's
    layout), held-out views likewise, relit views under the second procedural sky alone.
    Rendered with ``max_depth`` path vertices, so the interreflections are all there."""
    mesh, albedo = corner_mesh()
    spec_v = np.full(mesh.n_vertices, specular, np.float32)
    rough_v = np.full(mesh.n_vertices, roughness, np.float32)
    field = VertexField(mesh.faces, albedo, spec_v, rough_v)
    centre, radius = np.zeros(3), float(np.sqrt(3) / 2)
    cams = layout.orbit_cameras(_corner_directions(views), centre, radius, resolution)
    held = layout.orbit_cameras(_corner_directions(held_out, 0.5 / held_out), centre, radius, resolution)
    intensity = 0.6 * float(np.linalg.norm(cams[0].centre - centre)) ** 2
    settings = RenderSettings(spp=spp, max_depth=max_depth, integrator="path", hide_emitters=True)

    def render_set(root, cameras, names, lit, env=None, pixels=None):
        lights = [layout.paper_lights(c, intensity) if lit else [] for c in cameras]
        renderer = SceneRenderer(mesh, field, cameras, lights, env, settings, env_pixels=pixels, rgba=True)
        emit("progress", stage=f"synth:corner:{root.name}", iteration=len(cameras), iterations=len(cameras))
        return Capture(root, _write_views(root, renderer, cameras, lights, names, seed), env)

    capture = render_set(out, cams, [f"{i:04d}" for i in range(len(cams))], lit=True)
    gt_mesh = mesh.copy()
    gt_mesh.vertex_colors = albedo
    gt_mesh.attributes = {"specular": spec_v, "roughness": rough_v}
    save_mesh(out / "gt" / "mesh.ply", gt_mesh)
    fsio.write_json(out / "gt" / "material.json", {"albedo": CORNER_COLOURS, "specular": specular,
                                                   "roughness": roughness, "model": "lambert+ggx",
                                                   "per_vertex": "gt/mesh.ply"})
    names = [f"held{i:02d}" for i in range(len(held))]
    save_capture(render_set(out / "gt" / "held_out", held, names, lit=True))
    relit_pixels = procedural.sky(256, 60, -120, 250)  # synth's second sky ("sky2")
    relit_env = Environment(out / "gt" / "relit" / "env.exr", 1.0, 0.0)
    write_image(relit_env.path, relit_pixels)
    save_capture(render_set(out / "gt" / "relit", held, names, lit=False, env=relit_env, pixels=relit_pixels))
    capture.ground_truth = {"mesh": "gt/mesh.ply", "material": "gt/material.json", "held_out": "gt/held_out",
                            "relit": "gt/relit"}
    capture.provenance = {"source": "bench", "scene": "corner", "views": len(cams), "resolution": resolution,
                          "spp": spp, "max_depth": max_depth}
    save_capture(capture)


def build_video(out: Path, emit, frames: int = 40, size: str = "640x360", samples: int = 16) -> None:
    """The video scene: ``bench realworld``'s Cycles orbit video (cached beside ``out`` in
    ``video_orbit``, rendered again only when its settings change), through
    ``capture-from-video`` into ``out``; then the truth mesh, carried into the capture's scene
    frame by the similarity that maps its solved camera centres onto the rendered ones
    (Umeyama), is written to ``gt/mesh.ply`` and named the capture's ground truth, so runs are
    scored as on the synthetic scenes."""
    parser = argparse.ArgumentParser()
    realworld.add_arguments(parser)
    args = parser.parse_args(["--out", str(Path(out).parent / "video_orbit"), "--frames", str(frames),
                              "--size", size, "--samples", str(samples)])
    args.out.mkdir(parents=True, exist_ok=True)
    emit("progress", stage="synth:video:render", iteration=0, iterations=2)
    orbit = realworld.render(args)
    emit("progress", stage="synth:video:capture-from-video", iteration=1, iterations=2)
    _launch.run(_launch.backend("capture-from-video", orbit / "orbit.mp4", "--masks", orbit / "masks", "--env", args.env,
                                "--out", out, "--frames", frames, "--overwrite"), what="capture-from-video")
    truth = json.loads((orbit / "truth.json").read_text())
    capture = load_capture(out)
    ours = np.array([f.camera.camera_to_world[:3, 3] for f in capture.frames])
    theirs = np.array([np.asarray(truth["camera_to_world"][int(f.name)])[:3, 3] for f in capture.frames])
    to_scene = np.linalg.inv(align_similarity(ours, theirs))  # Blender's world -> the capture's frame
    gt = load_mesh(orbit / "truth.ply").transformed(to_scene)
    save_mesh(out / "gt" / "mesh.ply", Mesh(gt.vertices, gt.faces))
    capture.ground_truth = {"mesh": "gt/mesh.ply"}
    capture.provenance = dict(capture.provenance or {}, scene="video", truth_alignment="camera centres (Umeyama)")
    save_capture(capture)


SCENES = {s.name: s for s in [
    Scene("dragon", "the paper's dragon (Y up) as in bench geometry: 32 views at 128 px, two point lights per "
          "camera, constant glossy material (albedo 0.6, specular 0.3, roughness 0.3); 4 held-out views",
          _synth(mesh=str(DRAGON), up="y", views=32, resolution=128, lighting="points", albedo=[0.6, 0.6, 0.6],
                 specular=0.3, roughness=0.3, spp=256, max_depth=4, held_out=4)),
    Scene("blob_env", "the built-in blob with the procedural albedo texture under an HDR studio map, "
          "24 views at 128 px",
          _synth(mesh="blob", views=24, resolution=128, lighting="env", environment=_studio(), albedo="pattern",
                 specular=0.25, roughness=0.35, spp=256, max_depth=4, held_out=4)),
    Scene("corner", "a solid three-plane corner (red, blue, white planes), 24 views at 128 px all around "
          "under camera-mounted point lights, path traced with 8 vertices (colour bleeding inside)", build_corner),
    Scene("armadillo_env", "the Stanford armadillo under the forest HDR map (self-shadowing), 32 views at "
          "128 px, constant glossy material (albedo 0.6, specular 0.2, roughness 0.4); 4 held-out views",
          _synth(**ARMADILLO_ENV)),
    Scene("video", "the video path: a 40-frame 640x360 Cycles orbit video of Spot under the sunset map, no "
          "poses, through capture-from-video (SfM); F1 and Chamfer against the truth carried into its frame",
          build_video),
    Scene("tiny", "the blob, 8 views at 32 px, two point lights per camera (smoke test)",
          _synth(mesh="blob", views=8, resolution=32, lighting="points", albedo=[0.6, 0.6, 0.6], spp=16,
                 held_out=2)),
]}


def ensure(name: str, root: Path, emit) -> Path:
    """The scene's capture folder under ``root``, synthesised on first use (atomically)."""
    folder = Path(root) / name
    if not (folder / "capture.json").is_file():
        with fsio.atomic_dir(folder, replace=True) as tmp:
            SCENES[name].build(tmp, emit)
    return folder
