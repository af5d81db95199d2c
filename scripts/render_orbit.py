"""A hand-held orbit video of a textured object under an HDR map, rendered with Cycles (CPU).

    python scripts/render_orbit.py --out DIR [--mesh OBJ|PLY] [--env HDR] [options]

Runs with the bpy module (the venv's python); the backend never imports bpy, so benchmarks
call this as a subprocess. The object (a shared mesh, or an icosphere when none is given)
is centred at the origin, about 1 unit across, Z up, with a procedural two-scale noise
albedo (texture for SIFT) on a Principled BSDF. The world is the HDR map placed as the
capture format places it (Generated -> Mapping rotation Z -> Environment Texture) at
``--env-rotation`` degrees. The camera orbits once at about ``--elevation`` degrees with a
slow bob and hand-held jitter (smoothed random offsets of position, aim and roll).

Each frame is rendered once with a transparent film: its alpha is the object's mask, and
the background the camera sees is looked up in the map (the same convention, bilinear)
and laid under it (Blender 5 writes no Environment pass to the EXR). One exposure (fixed
from the first frame, like a phone with exposure locked) and the sRGB curve make 8-bit
frames. ``--check-background`` renders one opaque frame and reports how far the composite
is from it. Writes to DIR:

- ``orbit.mp4``: the frames as H.264 (yuv420p), ``--fps``
- ``masks/0000.png ...``: one 8-bit mask per video frame (index-paired): the object's alone
  with ``--ground`` (a textured plane it stands on, in the frames only)
- ``truth.ply``: the object in Blender's world frame
- ``truth.json``: environment (path, rotation, strength), exposure, camera intrinsics,
  per-frame camera-to-world matrices (Blender axes), render settings and seconds"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from pathlib import Path

import bpy  # before the backend (pymeshlab and bpy both ship Embree)
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.geometry.mesh import Mesh, load_mesh, save_mesh  # noqa: E402

SHARED = ROOT.parent / "shared" / "data"
DEFAULT_ENV = SHARED / "envmaps" / "venice_sunset_1k.hdr"


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="render_orbit.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True, help="folder to write (replaced)")
    p.add_argument("--mesh", type=Path, help="OBJ or PLY of the object (default: an icosphere)")
    p.add_argument("--up", choices=["y", "z"], default="y", help="the mesh file's up axis")
    p.add_argument("--env", type=Path, default=DEFAULT_ENV, help="equirectangular HDR map")
    p.add_argument("--env-rotation", type=float, default=40.0, help="degrees about Z (the truth to recover)")
    p.add_argument("--env-strength", type=float, default=1.0)
    p.add_argument("--frames", type=int, default=48, help="frames over one full orbit")
    p.add_argument("--size", default="640x360", help="WIDTHxHEIGHT (even numbers)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel")
    p.add_argument("--denoise", choices=["oidn", "none"], default="oidn")
    p.add_argument("--lens", type=float, default=28.0, help="focal length in mm on a 36 mm wide sensor")
    p.add_argument("--distance", type=float, default=1.9, help="orbit radius (object about 1 across)")
    p.add_argument("--elevation", type=float, default=25.0, help="mean camera elevation in degrees")
    p.add_argument("--jitter", type=float, default=1.0, help="hand-held shake (0 = a perfect orbit)")
    p.add_argument("--fps", type=int, default=24)
    p.add_argument("--crf", type=int, default=18, help="H.264 quality (lower is better)")
    p.add_argument("--threads", type=int, default=0, help="Cycles threads (0 = all cores)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--ground", action="store_true",
                   help="stand the object on a textured ground plane (in the frames, not in the masks)")
    p.add_argument("--check-background", action="store_true",
                   help="also render frame 0 with an opaque film and print how far the composite is from it")
    return p.parse_args(argv)


def object_mesh(path: Path | None, up: str) -> Mesh:
    """The mesh turned Z up, its bounding box centred at the origin, longest side 1."""
    if path is None:
        bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=0.5)
        ob = bpy.context.object
        v = np.array([x.co[:] for x in ob.data.vertices], np.float64)
        f = np.array([p.vertices[:] for p in ob.data.polygons], np.int64)
        bpy.data.objects.remove(ob)
        mesh = Mesh(v, f)
    else:
        mesh = load_mesh(path)
    v = np.asarray(mesh.vertices, np.float64)
    if up == "y":
        v = np.column_stack([v[:, 0], -v[:, 2], v[:, 1]])
    lo, hi = v.min(0), v.max(0)
    v = (v - 0.5 * (lo + hi)) / float((hi - lo).max())
    return Mesh(v, np.asarray(mesh.faces, np.int64))


def add_object(mesh: Mesh, seed: int) -> bpy.types.Object:
    data = bpy.data.meshes.new("object")
    data.from_pydata(mesh.vertices.tolist(), [], mesh.faces.tolist())
    data.update()
    for poly in data.polygons:
        poly.use_smooth = True
    ob = bpy.data.objects.new("object", data)
    bpy.context.scene.collection.objects.link(ob)
    mat = bpy.data.materials.new("textured")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    coords = nodes.new("ShaderNodeTexCoord")
    coarse, fine = nodes.new("ShaderNodeTexNoise"), nodes.new("ShaderNodeTexNoise")
    for node, scale in ((coarse, 2.5), (fine, 16.0)):
        node.noise_dimensions = "4D"  # W picks the pattern
        node.inputs["W"].default_value = float(seed)
        node.inputs["Scale"].default_value = scale
        node.inputs["Detail"].default_value = 4.0
        node.inputs["Roughness"].default_value = 0.6
        links.new(coords.outputs["Object"], node.inputs["Vector"])
    ramp = nodes.new("ShaderNodeValToRGB")  # fine blotches, dark to light: 0.04 .. 0.8
    links.new(fine.outputs["Fac"], ramp.inputs["Fac"])
    (lo, hi) = ramp.color_ramp.elements
    lo.position, lo.color = 0.42, (0.04, 0.04, 0.04, 1.0)
    hi.position, hi.color = 0.58, (0.8, 0.8, 0.8, 1.0)
    tint = nodes.new("ShaderNodeMix")  # hues from the coarse noise's colour
    tint.data_type = "RGBA"
    tint.blend_type = "MULTIPLY"
    tint.inputs["Factor"].default_value = 1.0
    links.new(ramp.outputs["Color"], tint.inputs["A"])
    links.new(coarse.outputs["Color"], tint.inputs["B"])
    saturate = nodes.new("ShaderNodeHueSaturation")
    saturate.inputs["Saturation"].default_value = 1.8
    saturate.inputs["Value"].default_value = 1.6
    links.new(tint.outputs["Result"], saturate.inputs["Color"])
    links.new(saturate.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.5
    ob.data.materials.append(mat)
    return ob


def add_ground(z: float, size: float = 8.0) -> bpy.types.Object:
    """A square plane at height ``z`` with a procedural albedo (browns by a fine noise, darker
    towards Voronoi cell edges: texture for SIFT, like a wooden table)."""
    data = bpy.data.meshes.new("ground")
    h = size / 2
    data.from_pydata([(-h, -h, z), (h, -h, z), (h, h, z), (-h, h, z)], [], [(0, 1, 2, 3)])
    data.update()
    ob = bpy.data.objects.new("ground", data)
    bpy.context.scene.collection.objects.link(ob)
    mat = bpy.data.materials.new("ground")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    coords = nodes.new("ShaderNodeTexCoord")
    noise, cells = nodes.new("ShaderNodeTexNoise"), nodes.new("ShaderNodeTexVoronoi")
    noise.inputs["Scale"].default_value = 24.0
    noise.inputs["Detail"].default_value = 6.0
    cells.inputs["Scale"].default_value = 9.0
    for node in (noise, cells):
        links.new(coords.outputs["Object"], node.inputs["Vector"])
    ramp = nodes.new("ShaderNodeValToRGB")  # wood-like browns by the fine noise
    links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    (lo, hi) = ramp.color_ramp.elements
    lo.position, lo.color = 0.3, (0.08, 0.045, 0.02, 1.0)
    hi.position, hi.color = 0.7, (0.45, 0.3, 0.16, 1.0)
    mix = nodes.new("ShaderNodeMix")  # darkened towards the cells' edges
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 0.6
    links.new(ramp.outputs["Color"], mix.inputs["A"])
    links.new(cells.outputs["Distance"], mix.inputs["B"])
    links.new(mix.outputs["Result"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.8
    ob.data.materials.append(mat)
    return ob


def object_alpha(scene, ground: bpy.types.Object, path: Path, samples: int = 4) -> np.ndarray:
    """The object's own coverage: the frame rendered again (``samples`` per pixel, no
    denoising) with the ground hidden from the camera (it still shadows and reflects)."""
    keep = scene.cycles.samples, scene.cycles.use_denoising, scene.render.filepath
    ground.visible_camera = False
    scene.cycles.samples, scene.cycles.use_denoising, scene.render.filepath = samples, False, str(path)
    bpy.ops.render.render(write_still=True)
    ground.visible_camera = True
    scene.cycles.samples, scene.cycles.use_denoising, scene.render.filepath = keep
    return read_rgba(path)[1]


def set_world(env: Path, rotation_z_deg: float, strength: float) -> None:
    """The capture format's chain (as addon/world.py builds it)."""
    world = bpy.data.worlds.new("world")
    bpy.context.scene.world = world
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    coords = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(rotation_z_deg))
    tex = nodes.new("ShaderNodeTexEnvironment")
    tex.projection = "EQUIRECTANGULAR"
    tex.image = bpy.data.images.load(str(env), check_existing=True)
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = strength
    output = nodes.new("ShaderNodeOutputWorld")
    links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])


def _smooth_noise(rng: np.random.Generator, n: int, dims: int, period: float) -> np.ndarray:
    """Unit-variance noise that wraps around the orbit, varying over about ``period`` frames."""
    k = np.fft.rfftfreq(n) * n
    spectrum = (rng.normal(size=(len(k), dims)) + 1j * rng.normal(size=(len(k), dims))) * np.exp(
        -0.5 * (k[:, None] * period / n) ** 2)
    spectrum[0] = 0
    x = np.fft.irfft(spectrum, n=n, axis=0)
    return x / max(x.std(), 1e-12)


def look_at(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """Camera-to-world (Blender axes: looks along -Z, Y up) from ``eye`` towards ``target``."""
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    c, s = math.cos(roll), math.sin(roll)
    right, up = c * right + s * up, -s * right + c * up
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, eye
    return m


def orbit(n: int, distance: float, elevation: float, jitter: float, seed: int) -> list[np.ndarray]:
    """One turn starting on the -Y side, elevation bobbing +-6 degrees twice per turn, with
    smoothed shake: position 2 %, aim 0.03 units, roll 1.5 degrees (times ``jitter``)."""
    rng = np.random.default_rng(seed)
    shake = _smooth_noise(rng, n, 3, 3.0) * 0.02 * distance * jitter
    aim = _smooth_noise(rng, n, 3, 3.0) * 0.03 * jitter
    roll = _smooth_noise(rng, n, 1, 3.0)[:, 0] * math.radians(1.5) * jitter
    poses = []
    for i in range(n):
        az = -math.pi / 2 + 2 * math.pi * i / n
        el = math.radians(elevation + 6.0 * math.sin(4 * math.pi * i / n))
        eye = distance * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        poses.append(look_at(eye + shake[i], aim[i], roll[i]))
    return poses


def configure(args, width: int, height: int) -> bpy.types.Object:
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args.samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.seed = args.seed
    scene.cycles.max_bounces = 4
    scene.cycles.use_denoising = args.denoise == "oidn"
    if scene.cycles.use_denoising:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    scene.render.threads_mode = "FIXED" if args.threads else "AUTO"
    if args.threads:
        scene.render.threads = args.threads
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"  # before the format (Blender 5)
    scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    scene.view_settings.view_transform = "Standard"
    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = 36.0
    cam_data.lens = args.lens
    cam_data.clip_start, cam_data.clip_end = 0.01, 100.0
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    return cam


def read_rgba(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(RGB premultiplied, alpha) of the render's multilayer EXR."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        channels = {name.split(".")[-1]: np.asarray(ch.pixels, np.float32) for name, ch in f.channels().items()
                    if ".Combined." in name}
    return np.stack([channels[c] for c in "RGB"], -1), channels["A"]


def background(env: np.ndarray, rotation_z_deg: float, strength: float, c2w: np.ndarray, fx: float,
               width: int, height: int) -> np.ndarray:
    """The map seen through each pixel centre: u = 0.5 - atan2(d'y, d'x) / 2pi, v = acos(d'z) / pi,
    d' = Rz(rotation) d (the capture format's convention), bilinear, wrapping in u."""
    x, y = np.meshgrid(np.arange(width) + 0.5 - width / 2, np.arange(height) + 0.5 - height / 2)
    d = np.stack([x / fx, -y / fx, -np.ones_like(x)], -1) @ c2w[:3, :3].T
    a = math.radians(rotation_z_deg)
    d = d @ np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]]).T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    h, w = env.shape[:2]
    u = (0.5 - np.arctan2(d[..., 1], d[..., 0]) / (2 * math.pi)) % 1.0 * w - 0.5
    v = np.arccos(np.clip(d[..., 2], -1, 1)) / math.pi * h - 0.5
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    fu, fv = (u - u0)[..., None], (v - v0)[..., None]
    v0, v1 = np.clip(v0, 0, h - 1), np.clip(v0 + 1, 0, h - 1)
    u0, u1 = u0 % w, (u0 + 1) % w
    top = env[v0, u0] * (1 - fu) + env[v0, u1] * fu
    bottom = env[v1, u0] * (1 - fu) + env[v1, u1] * fu
    return strength * (top * (1 - fv) + bottom * fv)


def srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(x * 255).astype(np.uint8)


def check_background(scene, cam, pose, env, args, fx, exr_dir: Path, exposure: float) -> None:
    """Frame 0 rendered with an opaque film vs. the composite, on pixels the object leaves bare."""
    cam.matrix_world = pose.T.tolist()
    scene.render.film_transparent = False
    scene.render.filepath = str(exr_dir / "opaque.exr")
    bpy.ops.render.render(write_still=True)
    opaque, _ = read_rgba(exr_dir / "opaque.exr")
    scene.render.film_transparent = True
    rgb, alpha = read_rgba(exr_dir / "0000.exr")
    height, width = alpha.shape
    ours = rgb + (1 - alpha[..., None]) * background(env, args.env_rotation, args.env_strength, pose, fx, width, height)
    bare = alpha < 1e-3
    diff = np.abs(srgb8(exposure * ours).astype(float) - srgb8(exposure * opaque).astype(float))
    print(json.dumps({"background_check": {"mean_abs_8bit": round(float(diff[bare].mean()), 3),
                                           "p99_abs_8bit": round(float(np.percentile(diff[bare], 99)), 3)}}),
          flush=True)


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    if width % 2 or height % 2:
        raise SystemExit("--size needs even numbers (H.264)")
    out = args.out
    shutil.rmtree(out, ignore_errors=True)
    (out / "masks").mkdir(parents=True)
    exr_dir = out / ".exr"
    exr_dir.mkdir()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = object_mesh(args.mesh, args.up)
    add_object(mesh, args.seed)
    ground = add_ground(float(mesh.vertices[:, 2].min())) if args.ground else None
    set_world(args.env, args.env_rotation, args.env_strength)
    cam = configure(args, width, height)
    poses = orbit(args.frames, args.distance, args.elevation, args.jitter, args.seed)
    scene = bpy.context.scene

    import av
    from PIL import Image

    from backend.capture.images import read_linear_rgb

    env = read_linear_rgb(args.env)[..., :3].astype(np.float32)
    fx = args.lens / 36.0 * width
    start = time.perf_counter()
    exposure = None
    with av.open(str(out / "orbit.mp4"), "w") as container:
        stream = container.add_stream("libx264", rate=args.fps)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": str(args.crf), "preset": "medium"}
        for i, pose in enumerate(poses):
            cam.matrix_world = pose.T.tolist()  # mathutils takes rows
            scene.render.filepath = str(exr_dir / f"{i:04d}.exr")
            bpy.ops.render.render(write_still=True)
            rgb, alpha = read_rgba(exr_dir / f"{i:04d}.exr")
            if exposure is None:  # the object's bright end to 0.8, kept for the whole video
                lum = (rgb / np.maximum(alpha, 1e-3)[..., None]).mean(-1)[alpha > 0.99]
                exposure = 0.8 / max(float(np.percentile(lum, 97)), 1e-6)
            behind = background(env, args.env_rotation, args.env_strength, pose, fx, width, height)
            frame = srgb8(exposure * (rgb + (1 - alpha[..., None]) * behind))
            # the film's alpha covers the ground too: the mask is the object's own coverage
            coverage = alpha if ground is None else object_alpha(scene, ground, exr_dir / f"{i:04d}_mask.exr")
            mask = np.round(np.clip(coverage, 0, 1) * 255).astype(np.uint8)
            Image.fromarray(mask).save(out / "masks" / f"{i:04d}.png")
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
            print(f"frame {i + 1}/{len(poses)} {time.perf_counter() - start:.0f} s", flush=True)
        for packet in stream.encode():
            container.mux(packet)
    seconds = time.perf_counter() - start
    if args.check_background:
        check_background(scene, cam, poses[0], env, args, fx, exr_dir, exposure)
    shutil.rmtree(exr_dir)
    save_mesh(out / "truth.ply", mesh)
    truth = {
        "environment": {"path": str(args.env.resolve()), "rotation_z_deg": args.env_rotation,
                        "strength": args.env_strength},
        "exposure": exposure,
        "camera": {"width": width, "height": height, "fx": fx, "fy": fx, "cx": width / 2, "cy": height / 2},
        "camera_to_world": [p.tolist() for p in poses],
        "mesh": str(args.mesh.resolve()) if args.mesh else "icosphere",
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "render_seconds": seconds,
        "blender": bpy.app.version_string,
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1))
    print(json.dumps({"frames": len(poses), "seconds": round(seconds, 1), "out": str(out)}), flush=True)
    return 0


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    sys.exit(main(argv))
