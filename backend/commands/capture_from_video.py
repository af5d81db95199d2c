"""``capture-from-video VIDEO --masks MASKS --env HDR --out CAPTURE``: a capture from a phone video.

Frames are picked (by stride or count, the sharpest of each stretch, blurred ones dropped),
cameras solved by SfM (pycolmap, one shared camera with radial distortion), frames and
masks undistorted, and the scene levelled, centred and scaled from the masks' visual hull
(Z up, object at the origin, about 1 unit across). ``--images DIR`` takes already
extracted frames instead of a video. Masks are a folder of images or a video with one mask
per source frame, paired by index (files in name order). The environment map is copied
with rotation 0 and strength 1: lighting alignment is a later step, and provenance says so.
Inputs are checked before any work starts; the output folder appears only when complete."""

from __future__ import annotations

import importlib
import shutil
from pathlib import Path

import numpy as np

from .. import fsio
from ..capture import load_capture
from ..capture.format import FILENAME, save_capture
from ..capture.images import read_mask, write_mask
from ..capture.importers.common import opencv_camera
from ..capture.model import Capture, Environment, Frame
from ..capture.undistort import needs_resampling, pinhole, resample
from ..capture.validate import validate_environment
from ..errors import require
from ..events import Emitter
from ..geometry.mesh import Mesh, save_mesh
from ..video.frames import Source, check_masks, open_source, pick_frames
from ..video.scene_frame import scene_frame
from ..video.sfm import SfmOptions, SfmResult, solve

DEFAULT_VIDEO_FRAMES = 60


def add_arguments(parser):
    parser.add_argument("video", nargs="?", metavar="VIDEO", help="the video (MP4, MOV, MKV, ...)")
    parser.add_argument("--images", metavar="DIR", help="a folder of already extracted frames instead of a video")
    parser.add_argument("--masks", required=True, metavar="MASKS",
                        help="object masks, one per source frame: a folder of images (name order) or a video")
    parser.add_argument("--env", required=True, metavar="HDR",
                        help="equirectangular HDR map of the lighting (EXR or HDR)")
    parser.add_argument("--out", required=True, metavar="CAPTURE", help="new capture folder to write")
    pick = parser.add_mutually_exclusive_group()
    pick.add_argument("--frames", type=int, metavar="N",
                      help=f"pick about N frames (default {DEFAULT_VIDEO_FRAMES} from a video, all from --images)")
    pick.add_argument("--stride", type=int, metavar="K", help="pick one frame in every K")
    parser.add_argument("--blur-ratio", type=float, default=0.5, metavar="R",
                        help="drop frames less sharp than R times their neighbourhood's median (0 keeps all)")
    parser.add_argument("--max-size", type=int, metavar="PX", help="downscale frames so the longer side is at most PX")
    parser.add_argument("--overwrite", action="store_true", help="replace CAPTURE if it exists")


def _check_arguments(args) -> tuple[Path, bool]:
    require((args.video is None) != (args.images is None), args.video or args.images,
            "give either a VIDEO or --images DIR", "pass exactly one of them")
    require(args.frames is None or args.frames >= 3, None, f"--frames {args.frames} is below 3", "give 3 or more")
    require(args.stride is None or args.stride >= 1, None, f"--stride {args.stride} is below 1", "give 1 or more")
    require(args.max_size is None or args.max_size >= 8, None, f"--max-size {args.max_size} is too small",
            "give at least 8 pixels")
    require(0 <= args.blur_ratio < 1, None, f"--blur-ratio {args.blur_ratio} is outside [0, 1)", "give e.g. 0.5")
    path = Path(args.images or args.video)
    if args.images is not None:
        require(path.is_dir(), path, "--images is not a folder", "give the folder of extracted frames")
    else:
        require(not path.is_dir(), path, "VIDEO is a folder", "give a video file, or the folder with --images")
    return path, args.images is not None


def run(args) -> int:
    path, is_folder = _check_arguments(args)
    frames = open_source(path)
    masks = open_source(args.masks)
    check_masks(frames, masks)
    env_path = Path(args.env)
    environment = Environment(env_path, 1.0, 0.0)
    validate_environment(Capture(root=env_path.parent, frames=[], environment=environment))
    stride, count = args.stride, args.frames
    if stride is None and count is None and not is_folder:
        count = DEFAULT_VIDEO_FRAMES
    emit = Emitter()
    out = Path(args.out)
    with fsio.atomic_dir(out, replace=args.overwrite) as tmp:
        work = tmp / ".work"
        emit("stage", stage="frames", source=str(path), frames=frames.count)
        selection = pick_frames(frames, stride, count, args.blur_ratio)
        require(len(selection.sharpness) == masks.count, masks.path,
                f"{masks.count} masks for {len(selection.sharpness)} decoded frames of {path.name}",
                "give one mask per source frame")
        names = _write_frames(frames, masks, selection.indices, work, is_folder)
        emit("frames", selected=selection.indices, blurred=selection.rejected)
        sfm = solve([work / "frames" / f"{n}.png" for n in names], work / "sfm", SfmOptions(), emit, source=path)
        emit("sfm", registered=sfm.registered, total=sfm.total,
             reprojection_error_px=sfm.reprojection_error_px, method=sfm.method)
        capture = _scene_capture(sfm, names, selection.indices, work, environment, Path(args.masks))
        capture.provenance.update(source="images" if is_folder else "video", path=str(path.resolve()),
                                  masks=str(Path(args.masks).resolve()),
                                  frames={"source_frames": frames.count, "stride": stride, "count": count,
                                          "blur_ratio": args.blur_ratio, "selected": selection.indices,
                                          "blurred": selection.rejected})
        written = importlib.import_module(".import", __package__).convert(capture, tmp, args.max_size)
        shutil.rmtree(work)
        save_capture(written)
        load_capture(tmp)  # what we wrote must read back and validate
    emit("done", result=str(out / FILENAME), frames=len(written.frames), registered=sfm.registered,
         total=sfm.total, reprojection_error_px=sfm.reprojection_error_px)
    return 0


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
    for i, mask in masks.masks(indices):
        write_mask(work / "masks" / f"{by_index[i]}.png", mask)
    return names


def _scene_capture(sfm: SfmResult, names: list[str], indices: list[int], work: Path,
                   environment: Environment, mask_source: Path) -> Capture:
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
    frames = [Frame(n, work / "frames" / f"{n}.png", frame.camera(c), mask=work / "masks" / f"{n}.png")
              for n, c in zip(registered, cameras)]
    points = work / "points.ply"
    save_mesh(points, Mesh(frame.point(sfm.points), np.zeros((0, 3), np.int64)))
    unregistered = [i for i, n in zip(indices, names) if n not in sfm.poses]
    provenance = {
        "sfm": dict(sfm.summary(), unregistered=unregistered),
        "scene_frame": {"world_from_sfm": frame.matrix.tolist(), "scale": frame.scale, "up": frame.up_from,
                        "size": frame.size_from},
        "lighting": {"aligned": False,
                     "note": "environment rotation 0 and strength 1 are placeholders, not estimated from the frames"},
    }
    return Capture(work, frames, environment, points, provenance)
