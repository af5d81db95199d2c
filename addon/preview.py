"""Relit previews: Cycles renders the reconstruction from an input frame's camera under
the run's own lighting (or another HDR), saved beside that frame as one image.

The run's lighting is what its material was fitted under (backend/lighting/fitted.py):

- ``captured``: the capture's map (times the staged material's light factor) and the
  frames' point lights;
- ``estimate``: the fitted RUN/environment.exr (strength 1, rotation 0, times the light
  factor) and the frames' point lights; fixed to the camera (``--lighting rig``) the map
  turns with the preview camera; a world + rig run (``--lighting world+rig``: a world-fixed
  map plus RUN/environment_rig.exr fixed to the camera, summed) previews under its world-fixed
  map alone: a World holds one environment texture, and the camera-fixed part (the light that
  turned with the frames' camera) is left out, so the preview is darker where that part lit;
- ``flash``: one point light at the preview camera's centre with the fitted intensity.

Rendering happens in a temporary scene, so the user's scene, world and render settings
stay as they were; only the image "SfT Relit Preview" is added or updated."""

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np

from . import world
from .io.capture_file import CaptureInfo
from .io.errors import require
from .io.files import png_bytes, write_atomic
from .images import read_rgba, to_display
from .scene_cameras import camera_object, configure_render

IMAGE_NAME = "SfT Relit Preview"
SCENE_NAME = ".sft_preview"  # the temporary scene a preview renders
ESTIMATED_MAP = "environment.exr"  # RUN/environment.exr: --lighting estimate and rig (docs/protocol.md)
SETTING_MODELS = {"ESTIMATE": ("estimate", "world"), "RIG": ("estimate", "camera"), "FLASH": ("flash", "world"),
                  "WORLD_RIG": ("estimate", "world+camera"), "CAPTURED": ("captured", "world")}
SUMMED_FRAME = "world+camera"  # report.json lighting.frame of --lighting world+rig


@dataclass
class PreviewLighting:
    """The light of a relit preview: an environment (``env``: path, strength, rotation_z_deg;
    ``camera_fixed``: the map turns with the camera, as a rig's), the frame's own point
    lights (``frame_lights``) and further point lights (``lights``: position, intensity in W/sr),
    with a line for the report (``describe``)."""

    env: dict | None = None
    camera_fixed: bool = False
    frame_lights: bool = True
    lights: list[dict] = field(default_factory=list)
    describe: str = ""


def _read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _options(argv: list) -> dict[str, str]:
    """A command line's ``--name value`` and ``--name=value`` options, the last one of each."""
    out = {}
    for i, arg in enumerate(map(str, argv)):
        if arg.startswith("--") and "=" in arg:
            name, value = arg.split("=", 1)
            out[name] = value
        elif arg.startswith("--") and i + 1 < len(argv):
            out[arg] = str(argv[i + 1])
    return out


def run_lighting(run_dir: Path | None, setting: str = "CAPTURED") -> dict:
    """What lit a run's fit: ``model`` (captured, estimate or flash), ``frame`` (world, or
    camera for a rig's map), ``file`` (the estimated map), ``intensity`` (the flash's RGB
    W/sr, None while unknown), ``light_factor`` and ``env`` (the map given with ``--env``, as
    path, strength and rotation_z_deg; None when the capture's own was used). Read from
    RUN/report.json once the run has finished, else from the command line it started with
    (RUN/command.json) and its last ``lighting`` event (RUN/events.jsonl), else from the
    Lighting ``setting``. Without a run folder nothing was fitted: the captured lighting."""
    out = {"model": "captured", "frame": "world", "file": None, "intensity": None, "light_factor": 1.0, "env": None}
    run = Path(run_dir) if run_dir else None
    if run is None or not run.is_dir():
        return out
    out["model"], out["frame"] = SETTING_MODELS.get(setting, ("captured", "world"))
    command = _read_json(run / "command.json")
    argv = command.get("argv") if isinstance(command, dict) else None
    options = _options(argv) if isinstance(argv, list) else {}
    if options.get("--env"):
        try:
            out["env"] = {"path": Path(options["--env"]), "strength": float(options.get("--env-strength", 1.0)),
                          "rotation_z_deg": float(options.get("--env-rotation", 0.0))}
        except ValueError:
            pass
    report = _read_json(run / "report.json")
    lighting = report.get("lighting") if isinstance(report, dict) else None
    if isinstance(lighting, dict):
        name = str(lighting.get("model", "captured"))
        out["model"] = "flash" if name == "flash" else "estimate" if name.startswith("environment map") else "captured"
        out["frame"] = lighting.get("frame") if lighting.get("frame") in ("camera", SUMMED_FRAME) else "world"
        out["intensity"] = lighting.get("intensity")
        out["file"] = run / str(lighting.get("file") or ESTIMATED_MAP)
        try:
            out["light_factor"] = float((report.get("material") or {}).get("light_factor") or 1.0)
        except (TypeError, ValueError, AttributeError):
            pass
    else:
        if isinstance(argv, list):
            out["model"], out["frame"] = {"estimate": ("estimate", "world"), "rig": ("estimate", "camera"),
                                          "world+rig": ("estimate", SUMMED_FRAME),
                                          "flash": ("flash", "world")}.get(options.get("--lighting"),
                                                                           ("captured", "world"))
        out["file"] = run / ESTIMATED_MAP
        if out["model"] == "flash":
            out["intensity"] = _last_flash_intensity(run / "events.jsonl")
    if out["model"] != "estimate":
        out["file"] = None
    return out


def _last_flash_intensity(events: Path):
    """The intensity of the last ``lighting`` event that has one (a run still fitting its flash)."""
    try:
        lines = events.read_text().splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        try:
            event = json.loads(line)
        except ValueError:
            continue
        if isinstance(event, dict) and event.get("event") == "lighting" and event.get("intensity") is not None:
            return event["intensity"]
    return None


def preview_lighting(info: CaptureInfo, run_dir: Path | None, setting: str, other_env: dict | None = None,
                     panel_env: dict | None = None) -> PreviewLighting:
    """The lighting a relit preview renders under: ``other_env`` (another HDR, alone) when
    given, else the run's own (:func:`run_lighting`; the module docstring). Under captured
    lighting the map is the run's ``--env``, else ``panel_env`` (the imported map Reconstruct
    would pass) when there is no run, else the capture's. Raises when that lighting cannot be
    had (a fitted map or flash not written yet, or no light at all)."""
    if other_env:
        return PreviewLighting(other_env, frame_lights=False, describe=f"under {Path(other_env['path']).name}")
    fitted = run_lighting(run_dir, setting)
    factor = fitted["light_factor"]
    has_lights = any(frame.lights for frame in info.frames)
    if fitted["model"] == "flash":
        value = fitted["intensity"]
        try:
            rgb = np.broadcast_to(np.asarray(value, np.float64).reshape(-1), (3,)).copy()
        except (TypeError, ValueError):
            rgb = None
        require(rgb is not None and bool(np.all(np.isfinite(rgb) & (rgb > 0))), run_dir,
                "the run has no fitted flash intensity yet",
                "wait for the run's first material stage, or choose Other HDR")
        shown = f"{rgb[0]:.4g}" if np.ptp(rgb) == 0 else ", ".join(f"{x:.4g}" for x in rgb)
        return PreviewLighting(frame_lights=False, lights=[{"camera": True, "intensity_w_per_sr": list(rgb)}],
                               describe=f"under the run's fitted flash ({shown} W/sr)")
    if fitted["model"] == "estimate":
        path = fitted["file"]
        require(path is not None and path.is_file(), path or run_dir, "the run has no estimated environment map yet",
                "reconstruct first (Lighting: Estimate writes RUN/environment.exr), or choose Other HDR")
        rig = fitted["frame"] == "camera"
        part = " (its world-fixed part; the camera-fixed map is not shown)" if fitted["frame"] == SUMMED_FRAME else ""
        return PreviewLighting({"path": path, "strength": factor, "rotation_z_deg": 0.0}, camera_fixed=rig,
                               describe="under the run's estimated environment" + (" (on the camera)" if rig else "")
                               + part)
    env = fitted["env"] or (panel_env if not run_dir or not Path(run_dir).is_dir() else None) or info.environment
    if env is not None and factor != 1.0:
        env = dict(env, strength=env["strength"] * factor)
    require(env is not None or has_lights, info.root, "the capture has no lighting to render under",
            "import an environment map, reconstruct with Lighting: Estimate, or choose Other HDR")
    return PreviewLighting(env, describe="under the captured " + ("environment" if env else "lights"))


def rig_rotation(camera_to_world) -> tuple[float, float, float]:
    """The Mapping node's Euler rotation (XYZ, radians) of a map fixed to a camera: the lookup
    direction is the rig frame's d_rig = A^T d, A's columns the camera's +z (toward the
    camera), +x (right) and +y (up) in world coordinates (backend.capture.model.Environment)."""
    from mathutils import Matrix

    r = np.asarray(camera_to_world, np.float64)[:3, :3]
    r = r / np.cbrt(abs(np.linalg.det(r)))
    axes = np.stack([r[:, 2], r[:, 0], r[:, 1]], 1)
    return tuple(Matrix(axes.T.tolist()).to_euler("XYZ"))


def cycles_device(context, choice: str) -> str:
    """'GPU' when asked for (or AUTO) and Cycles has a GPU configured, else 'CPU'."""
    if choice == "CPU":
        return "CPU"
    addon = context.preferences.addons.get("cycles")
    prefs = addon.preferences if addon else None
    if prefs is None or getattr(prefs, "compute_device_type", "NONE") == "NONE":
        return "CPU"
    prefs.refresh_devices()
    return "GPU" if any(d.use and d.type != "CPU" for d in prefs.devices) else "CPU"


def _point_light(light: dict) -> bpy.types.Object:
    """A capture point light: radiant intensity I (W/sr) is Blender power 4 pi I (W)."""
    intensity = np.asarray(light.get("intensity_w_per_sr", light.get("intensity", 1.0)), float)
    intensity = np.broadcast_to(intensity, 3)
    peak = float(intensity.max())
    data = bpy.data.lights.new(".sft_preview_light", "POINT")
    data.energy = 4.0 * math.pi * peak
    data.color = tuple(intensity / peak) if peak > 0 else (1.0, 1.0, 1.0)
    data.shadow_soft_size = 0.0
    obj = bpy.data.objects.new(".sft_preview_light", data)
    obj.location = tuple(light["position"])
    return obj


def render(context, obj: bpy.types.Object, info: CaptureInfo, frame_index: int, lighting: PreviewLighting,
           samples: int, percentage: int, device: str, path: Path, blend: Path | None = None) -> str:
    """Render ``obj`` from frame ``frame_index``'s camera under ``lighting`` into the PNG ``path``;
    with ``blend``, write that render's scene (named :data:`SCENE_NAME`) to the .blend file
    instead, for a worker to render (``addon/worker.py render BLEND SCENE``). Returns the
    scene's name."""
    frame = info.frames[frame_index]
    scene = bpy.data.scenes.new(SCENE_NAME)
    temporary = []
    try:
        scene.render.engine = "CYCLES"
        scene.cycles.samples = samples
        scene.cycles.use_denoising = False
        scene.cycles.device = cycles_device(context, device)
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        scene.render.film_transparent = False
        scene.render.image_settings.file_format = "PNG"
        scene.render.image_settings.color_mode = "RGB"
        scene.render.image_settings.color_depth = "8"
        scene.render.filepath = str(path)
        configure_render(scene, frame.camera, percentage)
        scene.collection.objects.link(obj)
        camera = camera_object(".sft_preview_camera", frame.camera)
        temporary.append(camera)
        scene.collection.objects.link(camera)
        scene.camera = camera
        env = lighting.env
        if env:  # else no world: black
            scene.world = bpy.data.worlds.new(".sft_preview")
            image = world.load_environment_image(env["path"])
            image.reload()  # a run rewrites its map under one name
            world.set_environment(scene.world, image, env["strength"], env["rotation_z_deg"])
            if lighting.camera_fixed:
                mapping = next(n for n in scene.world.node_tree.nodes if n.type == "MAPPING")
                mapping.inputs["Rotation"].default_value = rig_rotation(frame.camera.matrix_world)
        centre = [float(x) for x in np.asarray(frame.camera.matrix_world)[:3, 3]]
        lights = (list(frame.lights) if lighting.frame_lights else []) + [
            dict(light, position=centre) if light.get("camera") else light for light in lighting.lights]
        for light in lights:
            temporary.append(_point_light(light))
            scene.collection.objects.link(temporary[-1])
        if blend is None:
            bpy.ops.render.render(write_still=True, scene=scene.name)
        else:
            bpy.data.libraries.write(str(blend), {scene}, path_remap="ABSOLUTE", fake_user=True)
        return scene.name
    finally:
        world_block = scene.world
        bpy.data.scenes.remove(scene)
        if world_block is not None:
            bpy.data.worlds.remove(world_block)
        for tmp in temporary:
            data = tmp.data
            bpy.data.objects.remove(tmp)
            (bpy.data.cameras if data.id_type == "CAMERA" else bpy.data.lights).remove(data)


def side_by_side(render_path: Path, frame_path: Path, out_path: Path) -> tuple[int, int]:
    """Write the render and the input frame (resized to it) side by side; returns its size."""
    rendered, _ = read_rgba(render_path)
    h, w = rendered.shape[:2]
    frame, linear = read_rgba(frame_path)
    rows = (np.arange(h) * frame.shape[0] // h)[:, None]
    cols = (np.arange(w) * frame.shape[1] // w)[None, :]
    frame = to_display(frame[rows, cols, :3], linear)
    both = np.concatenate([rendered[..., :3], frame], axis=1)
    write_atomic(out_path, png_bytes(np.rint(both * 255)))
    return 2 * w, h


def show(path: Path, name: str = IMAGE_NAME) -> bpy.types.Image:
    """Load (or reload) the image file ``path`` as the image ``name`` (default "SfT Relit Preview")."""
    image = bpy.data.images.get(name)
    if image is None:
        image = bpy.data.images.load(str(path))
        image.name = name
    else:
        image.filepath = str(path)
        image.reload()
    return image
