"""Library of ``capture-from-video`` (and ``reconstruct VIDEO``): check the inputs, then write
the capture (frames, SfM, scene frame, undistortion, lighting alignment) atomically.

Without masks, SfM runs on the frames alone, the masks are made from its result
(:mod:`backend.masks`), and the silhouette refinement of the cameras follows with them.

The environment map is optional: without one the capture holds cameras only, and
the lighting is given later (``reconstruct --env``)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import fsio
from ..capture.convert import convert
from ..capture.format import save_capture
from ..capture.images import read_mask, read_rgba, write_mask
from ..capture.importers.common import opencv_camera
from ..capture.load import load_capture
from ..capture.model import Capture, Environment, Frame
from ..capture.undistort import needs_resampling, pinhole, resample
from ..capture.validate import validate_environment
from ..errors import InputError, require
from ..geometry.init.carve import carve
from ..geometry.init.hull import HullConfig
from ..geometry.mesh import Mesh, save_mesh
from ..lighting.align import align_lighting
from ..masks import MaskOptions, make_masks, parse_object_box
from ..masks.region import NO_OBJECT_FIX
from ..masks.segment import OnnxSegmenter
from .frames import Source, check_masks, open_source, pick_frames
from .scene_frame import scene_frame
from .sfm import SfmOptions, SfmResult, solve
from .silhouettes import refine as refine_with_silhouettes

DEFAULT_VIDEO_FRAMES = 60
HULL_FACES = 3000  # the coarse mesh the lighting is aligned against
HULL_GRID = 64


def add_lighting_arguments(parser):
    parser.add_argument("--env-rotation", type=float, metavar="DEG",
                        help="known rotation of the environment about Z (degrees); only its strength is estimated")
    parser.add_argument("--no-align-lighting", dest="align_lighting", action="store_false",
                        help="do not estimate the lighting: keep the rotation (--env-rotation, default 0) and strength 1")


@dataclass
class VideoInputs:
    """Checked inputs of a capture from a video (or a folder of frames)."""

    path: Path
    is_folder: bool
    frames: Source
    masks: Source | None  # None: made automatically (backend.masks)
    environment: Environment | None
    stride: int | None = None
    count: int | None = None
    blur_ratio: float = 0.5
    max_size: int | None = None
    align_lighting: bool = True
    env_rotation: float | None = None
    materials: Path | None = None  # label images named like the frames (integer labels, 0 = unassigned)
    mask_options: MaskOptions | None = None  # how automatic masks are made (masks is None)


def check_inputs(args, is_folder: bool | None = None) -> VideoInputs:
    """Every check that needs no decoding: options, the sources, mask count and size, the map.

    ``args`` needs ``masks`` (None: automatic masks, shaped by ``object_box`` and
    ``mask_model`` when present) and ``env``; the video is ``args.video`` or ``args.images``
    (capture-from-video), or ``args.capture`` (reconstruct: a folder is taken as frames)."""
    video, images = getattr(args, "video", None), getattr(args, "images", None)
    if hasattr(args, "capture"):
        path = Path(args.capture)
        is_folder = path.is_dir()
    else:
        require((video is None) != (images is None), video or images,
                "give either a VIDEO or --images DIR", "pass exactly one of them")
        path = Path(images or video)
        is_folder = images is not None
        if is_folder:
            require(path.is_dir(), path, "--images is not a folder", "give the folder of extracted frames")
        else:
            require(not path.is_dir(), path, "VIDEO is a folder", "give a video file, or the folder with --images")
    frames_n, stride = getattr(args, "frames", None), getattr(args, "stride", None)
    max_size, blur_ratio = getattr(args, "max_size", None), getattr(args, "blur_ratio", 0.5)
    require(frames_n is None or frames_n >= 3, None, f"--frames {frames_n} is below 3", "give 3 or more")
    require(stride is None or stride >= 1, None, f"--stride {stride} is below 1", "give 1 or more")
    require(max_size is None or max_size >= 8, None, f"--max-size {max_size} is too small", "give at least 8 pixels")
    require(0 <= blur_ratio < 1, None, f"--blur-ratio {blur_ratio} is outside [0, 1)", "give e.g. 0.5")
    rotation = getattr(args, "env_rotation", None)
    require(rotation is None or np.isfinite(rotation), None, "--env-rotation is not a finite number",
            "give the rotation in degrees")
    frames = open_source(path)
    masks, mask_options = None, None
    if args.masks is not None:
        masks = open_source(args.masks)
        check_masks(frames, masks)
    else:
        mask_options = automatic_mask_options(getattr(args, "object_box", None), getattr(args, "mask_model", None))
    environment = None
    if args.env is not None:
        env_path = Path(args.env)
        require(env_path.is_file(), env_path, "environment map not found", "give an EXR or HDR file")
        environment = Environment(env_path, 1.0, rotation or 0.0)
        validate_environment(Capture(root=env_path.parent, frames=[], environment=environment))
    if stride is None and frames_n is None and not is_folder:
        frames_n = DEFAULT_VIDEO_FRAMES
    materials = getattr(args, "materials", None)
    if materials is not None:
        materials = Path(materials)
        require(materials.is_dir(), materials, "--materials is not a folder",
                "give the folder of material label images, named like the frames")
    return VideoInputs(path, is_folder, frames, masks, environment, stride, frames_n, blur_ratio, max_size,
                       getattr(args, "align_lighting", True), rotation, materials, mask_options)


def add_mask_arguments(parser):
    parser.add_argument("--object-box", metavar="X0,Y0,Z0,X1,Y1,Z1",
                        help="without --masks: the object's box in the orbit frame (origin at the point the cameras "
                             "circle, Z up, units of the orbit radius) instead of the points near that point")
    parser.add_argument("--mask-model", metavar="FILE.onnx",
                        help="without --masks: segment each frame with this ONNX salient-object model (OpenCV dnn) "
                             "instead of GrabCut; the masks are checked against each other the same way")


def automatic_mask_options(object_box: str | None, mask_model: str | None) -> MaskOptions:
    """The options of automatic masks, checked (the model is read once here: a bad file fails now)."""
    options = MaskOptions(object_box=parse_object_box(object_box))
    if mask_model is not None:
        model = Path(mask_model)
        require(model.is_file(), model, "mask model not found", "give an ONNX file, or leave --mask-model out")
        OnnxSegmenter(model, options.model_size)
        options.model = model
    return options


def write_capture(inputs: VideoInputs, out: Path, emit, overwrite: bool = False) -> tuple[Capture, SfmResult]:
    """Frames, SfM, scene frame, undistortion and lighting alignment into the new folder ``out``."""
    path, frames, masks = inputs.path, inputs.frames, inputs.masks
    with fsio.atomic_dir(out, replace=overwrite) as tmp:
        work = tmp / ".work"
        emit("stage", stage="frames", source=str(path), frames=frames.count)
        selection = pick_frames(frames, inputs.stride, inputs.count, inputs.blur_ratio)
        require(masks is None or len(selection.sharpness) == masks.count, masks and masks.path,
                f"{masks and masks.count} masks for {len(selection.sharpness)} decoded frames of {path.name}",
                "give one mask per source frame")
        names = _write_frames(frames, masks, selection.indices, work, inputs.is_folder)
        emit("frames", selected=selection.indices, blurred=selection.rejected)
        images = [work / "frames" / f"{n}.png" for n in names]
        if masks is not None:
            sfm = solve(images, work / "sfm", SfmOptions(), emit, source=path,
                        masks=[work / "masks" / f"{n}.png" for n in names])
            mask_report = None
        else:
            sfm, mask_report = _solve_with_automatic_masks(images, work, inputs.mask_options, emit, path)
        emit("sfm", registered=sfm.registered, total=sfm.total,
             reprojection_error_px=sfm.reprojection_error_px, method=sfm.method, silhouettes=sfm.silhouettes)
        capture = _scene_capture(sfm, names, selection.indices, work, inputs.environment,
                                 masks.path if masks is not None else work / "masks", inputs.materials)
        if mask_report is not None:
            capture.provenance["masks_automatic"] = mask_report.summary()
        capture.provenance.update(source="images" if inputs.is_folder else "video", path=str(path.resolve()),
                                  masks=str(Path(masks.path).resolve()) if masks is not None else "automatic",
                                  frames={"source_frames": frames.count, "stride": inputs.stride,
                                          "count": inputs.count, "blur_ratio": inputs.blur_ratio,
                                          "selected": selection.indices, "blurred": selection.rejected})
        written = convert(capture, tmp, inputs.max_size)
        shutil.rmtree(work)
        if inputs.align_lighting and written.environment is not None:
            align_capture_lighting(written, inputs.env_rotation, emit)
        save_capture(written)
        load_capture(tmp)  # what we wrote must read back and validate
    return written, sfm


def _solve_with_automatic_masks(images: list[Path], work: Path, options: MaskOptions, emit, source: Path):
    """SfM on the frames alone, masks from its result (written beside the frames as PNG), then
    the silhouette refinement with them. Frames without a consistent mask lose their camera."""
    try:
        sfm = solve(images, work / "sfm", SfmOptions(), emit, source=source)
    except InputError as err:
        raise InputError(err.path, f"no object can be isolated: {err.problem}", NO_OBJECT_FIX) from None
    from PIL import Image

    frames = {}
    for p in images:
        if p.stem in sfm.poses:
            with Image.open(p) as im:
                frames[p.stem] = np.asarray(im.convert("RGB"))
    report = make_masks(frames, sfm, options, emit, where=source)
    sfm.seconds["masks"] = report.seconds
    for name in sfm.names:
        if name in report.masks:
            write_mask(work / "masks" / f"{name}.png", report.masks[name])
        else:
            sfm.poses.pop(name, None)
    emit("stage", stage="silhouettes")
    sfm, sfm.silhouettes = refine_with_silhouettes(sfm, report.masks, SfmOptions().silhouettes)
    return sfm, report


def align_capture_lighting(capture: Capture, rotation_z_deg: float | None, emit) -> None:
    """Estimate the environment's rotation (unless given) and strength against the masks' visual
    hull, and record them (provenance "estimated") with the loss curve in the capture."""
    emit("stage", stage="lighting")
    hull = carve(capture, HULL_FACES, HullConfig(grid=HULL_GRID))
    env = capture.environment
    estimate = align_lighting(capture, hull, read_rgba(env.path)[0][..., :3], rotation_z_deg=rotation_z_deg,
                              emit=emit)
    capture.environment = Environment(env.path, estimate.strength, estimate.rotation_z_deg, "estimated")
    capture.camera_response = estimate.response
    capture.provenance["lighting"] = dict(estimate.provenance(), hull_faces=hull.n_faces,
                                          rotation_given=rotation_z_deg is not None)


def lighting_summary(capture: Capture) -> dict | None:
    if capture.environment is None:
        return None
    lighting = capture.provenance.get("lighting", {})
    return {"aligned": bool(lighting.get("aligned")), "rotation_z_deg": capture.environment.rotation_z_deg,
            "strength": capture.environment.strength, "loss": lighting.get("loss")}


def _write_frames(frames: Source, masks: Source, indices: list[int], work: Path, is_folder: bool) -> list[str]:
    """Selected frames as PNG and their masks, named by source file stem or frame index."""
    names = [frames.files[i].stem for i in indices] if is_folder else [f"{i:05d}" for i in indices]
    require(len(set(names)) == len(names), frames.path, "two frames share a file name stem",
            "give frames unique names (e.g. 0001.png, 0002.png)")
    by_index = dict(zip(indices, names))
    from PIL import Image

    (work / "frames").mkdir(parents=True, exist_ok=True)
    for i, rgb in frames.frames(indices):
        Image.fromarray(rgb).save(work / "frames" / f"{by_index[i]}.png")
    (work / "masks").mkdir(parents=True, exist_ok=True)
    for i, mask in (masks.masks(indices) if masks is not None else ()):
        write_mask(work / "masks" / f"{by_index[i]}.png", mask)
    return names


def _scene_capture(sfm: SfmResult, names: list[str], indices: list[int], work: Path,
                   environment: Environment, mask_source: Path, materials: Path | None = None) -> Capture:
    """Registered frames with their cameras in the scene frame, the sparse points, provenance."""
    registered = [n for n in names if n in sfm.poses]
    K = np.array([[sfm.fx, 0, sfm.cx], [0, sfm.fy, sfm.cy], [0, 0, 1.0]])
    cameras = [opencv_camera(K, sfm.poses[n][:, :3], sfm.poses[n][:, 3], sfm.width, sfm.height,
                             pixel_offset=0.0, distortion=sfm.distortion) for n in registered]

    def undistorted_masks():
        for name, camera in zip(registered, cameras):
            mask = read_mask(work / "masks" / f"{name}.png")
            yield resample(mask, camera) if needs_resampling(camera) else mask

    frame = scene_frame([pinhole(c) for c in cameras], undistorted_masks(), sfm.points, where=mask_source)
    frames = [Frame(n, work / "frames" / f"{n}.png", frame.camera(c), mask=work / "masks" / f"{n}.png",
                    material_mask=_label_image(materials, n)) for n, c in zip(registered, cameras)]
    points = work / "points.ply"
    save_mesh(points, Mesh(frame.point(sfm.points), np.zeros((0, 3), np.int64)))
    unregistered = [i for i, n in zip(indices, names) if n not in sfm.poses]
    provenance = {
        "sfm": dict(sfm.summary(), unregistered=unregistered),
        "scene_frame": {"world_from_sfm": frame.matrix.tolist(), "scale": frame.scale, "up": frame.up_from,
                        "size": frame.size_from},
        "lighting": {"aligned": False,
                     "note": "environment rotation and strength as given (default 0 and 1), not estimated"},
    }
    return Capture(work, frames, environment, points, provenance)


def _label_image(folder: Path | None, name: str) -> Path | None:
    """The material label image of frame ``name`` (same stem, any image suffix), if given."""
    if folder is None:
        return None
    return next((p for p in sorted(folder.glob(f"{name}.*")) if p.suffix.lower() in (".png", ".tif", ".tiff")), None)
