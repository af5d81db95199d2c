"""Write the material labels Reconstruct would use as colour overlays on the frames (one PNG
per frame), for a look before reconstructing; one JSON object on stdout."""

from __future__ import annotations

import json
from pathlib import Path

from ..capture.load import load_capture
from ..errors import InputError
from ..material.labels import write_label_previews


def add_arguments(parser):
    parser.add_argument("--capture", required=True, type=Path, help="capture folder (capture.json)")
    parser.add_argument("--materials", dest="n_materials", metavar="N|auto", default="auto",
                        help="materials to cluster the object's colours into, or auto (as Reconstruct)")
    parser.add_argument("--out", type=Path, help="folder for the overlays (default: CAPTURE/labels_preview)")


def run(args) -> int:
    n = args.n_materials if args.n_materials == "auto" else _count(args.n_materials)
    out = args.out or args.capture / "labels_preview"
    summary = write_label_previews(load_capture(args.capture), n, out)
    print(json.dumps({"event": "done", **summary}), flush=True)
    return 0


def _count(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise InputError(None, f"--materials {text} is not a count", "give a whole number of 1 or more, or auto")
    return value
