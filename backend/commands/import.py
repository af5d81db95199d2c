"""``import SRC --out CAPTURE``: write any importable capture in our format.

The conversion itself is :func:`backend.capture.convert.import_capture`. The output folder
appears only once it is complete and validated."""

from __future__ import annotations

from pathlib import Path

from ..capture.convert import import_capture
from ..capture.format import FILENAME
from ..events import Emitter


def add_arguments(parser):
    parser.add_argument("source", metavar="SRC",
                        help="capture folder, transforms.json, COLMAP model, IDR npz folder, Middlebury *_par.txt "
                             "or AliceVision folder")
    parser.add_argument("--out", required=True, metavar="CAPTURE", help="new capture folder to write")
    parser.add_argument("--max-size", type=int, metavar="PX", help="downscale frames so the longer side is at most PX")
    parser.add_argument("--frames", type=int, metavar="N", help="keep N frames, evenly spaced")
    parser.add_argument("--images", metavar="DIR", help="frames folder of a COLMAP model (default: images/ beside it)")
    parser.add_argument("--overwrite", action="store_true", help="replace CAPTURE if it exists")


def run(args) -> int:
    out = Path(args.out)
    written = import_capture(Path(args.source), out, args.max_size, args.frames, args.images, args.overwrite)
    Emitter()("done", result=str(out / FILENAME), frames=len(written.frames),
              resampled=written.provenance["import"]["resampled_frames"])
    return 0
