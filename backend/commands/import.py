"""``import SRC --out CAPTURE``: write any importable capture in our format.

The conversion itself is :func:`backend.capture.convert.convert`. The output folder appears
only once it is complete and validated."""

from __future__ import annotations

import shutil
from pathlib import Path

from .. import fsio
from ..capture import load_capture
from ..capture.convert import convert, select
from ..capture.format import FILENAME, save_capture
from ..capture.importers import import_any
from ..capture.model import Capture
from ..capture.validate import validate_capture
from ..errors import require
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
    require(args.max_size is None or args.max_size >= 8, None, f"--max-size {args.max_size} is too small",
            "give at least 8 pixels")
    require(args.frames is None or args.frames >= 1, None, f"--frames {args.frames} is below 1", "give 1 or more")
    out = Path(args.out)
    with fsio.atomic_dir(out, replace=args.overwrite) as tmp:
        work = tmp / ".import"
        capture = read_source(Path(args.source), work, args.images)
        validate_capture(capture)
        written = convert(select(capture, args.frames), tmp, args.max_size)
        shutil.rmtree(work, ignore_errors=True)
        save_capture(written)
        load_capture(tmp)  # what we wrote must read back and validate
    Emitter()("done", result=str(out / FILENAME), frames=len(written.frames),
              resampled=written.provenance["import"]["resampled_frames"])
    return 0


def read_source(src: Path, workdir: Path, images: str | None) -> Capture:
    if (src.is_dir() and (src / FILENAME).is_file()) or src.name == FILENAME:
        return load_capture(src, validate=False)
    return import_any(src, workdir=workdir, images=images)
