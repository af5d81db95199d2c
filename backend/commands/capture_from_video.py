"""``capture-from-video VIDEO [--masks MASKS] [--env HDR] --out CAPTURE``: a capture from a phone video.

Frames are picked (by stride or count, the sharpest of each stretch, blurred ones dropped),
cameras solved by SfM (pycolmap, one shared camera with radial distortion), frames and
masks undistorted, and the scene levelled, centred and scaled from the masks' visual hull
(Z up, object at the origin, about 1 unit across). ``--images DIR`` takes already
extracted frames instead of a video. Masks are a folder of images or a video with one mask
per source frame, paired by index (files in name order); without ``--masks`` they are made from the
SfM result (:mod:`backend.masks`: the points the orbit circles, GrabCut per frame, the masks'
visual hull as a check; ``--object-box`` gives the object's region, ``--mask-model`` an ONNX
model instead of GrabCut), written into the capture's masks folder, and frames whose mask
disagrees with the others are dropped (counted in the report). The environment map (optional) is copied and
aligned with the frames (rotation about Z and strength, :mod:`backend.lighting`) against the
masks' visual hull; ``--env-rotation`` gives a known rotation (the strength is still
estimated) and ``--no-align-lighting`` keeps the given rotation (default 0) and strength 1.
Inputs are checked before any work starts; the output folder appears only when complete.
``reconstruct VIDEO --masks MASKS --env HDR`` runs the same code (:func:`check_inputs`,
:func:`write_capture`) into RUN/capture."""

from __future__ import annotations

from pathlib import Path

from ..capture.format import FILENAME
from ..events import Emitter
from ..video.inputs import (DEFAULT_VIDEO_FRAMES, add_lighting_arguments, add_mask_arguments, check_inputs,
                            lighting_summary, write_capture)


def add_arguments(parser):
    parser.add_argument("video", nargs="?", metavar="VIDEO", help="the video (MP4, MOV, MKV, ...)")
    parser.add_argument("--images", metavar="DIR", help="a folder of already extracted frames instead of a video")
    parser.add_argument("--masks", metavar="MASKS",
                        help="object masks, one per source frame: a folder of images (name order) or a video; "
                             "without it they are made automatically from the SfM result")
    parser.add_argument("--env", metavar="HDR",
                        help="equirectangular HDR map of the lighting (EXR or HDR), aligned to the frames; "
                             "without it the capture holds cameras only (give the map to reconstruct --env)")
    parser.add_argument("--materials", metavar="DIR",
                        help="material label images (0 = unassigned, 1-255 = material), named like the frames "
                             "(with --images); they become the capture's material masks")
    parser.add_argument("--out", required=True, metavar="CAPTURE", help="new capture folder to write")
    pick = parser.add_mutually_exclusive_group()
    pick.add_argument("--frames", type=int, metavar="N",
                      help=f"pick about N frames (default {DEFAULT_VIDEO_FRAMES} from a video, all from --images)")
    pick.add_argument("--stride", type=int, metavar="K", help="pick one frame in every K")
    parser.add_argument("--blur-ratio", type=float, default=0.5, metavar="R",
                        help="drop frames less sharp than R times their neighbourhood's median (0 keeps all)")
    parser.add_argument("--max-size", type=int, metavar="PX", help="downscale frames so the longer side is at most PX")
    parser.add_argument("--overwrite", action="store_true", help="replace CAPTURE if it exists")
    add_lighting_arguments(parser)
    add_mask_arguments(parser)


def run(args) -> int:
    inputs = check_inputs(args)
    emit = Emitter()
    out = Path(args.out)
    written, sfm = write_capture(inputs, out, emit, overwrite=args.overwrite)
    emit("done", result=str(out / FILENAME), frames=len(written.frames), registered=sfm.registered,
         total=sfm.total, reprojection_error_px=sfm.reprojection_error_px, silhouettes=sfm.silhouettes,
         lighting=lighting_summary(written), masks=written.provenance.get("masks_automatic"))
    return 0


