"""``synth``: render a synthetic capture of a mesh (or the built-in procedural object)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from ..errors import require
from ..events import Emitter
from ..synth.capture import SynthSpec, write_synthetic_capture

MAX_DRIFT_STOPS = 2.0


def add_arguments(parser):
    d = SynthSpec()
    parser.add_argument("--out", required=True, type=Path, help="capture folder to write (must be new or empty)")
    parser.add_argument("--mesh", default=d.mesh, help="mesh file (OBJ/PLY), or 'blob' for the built-in object")
    parser.add_argument("--up", choices=["z", "y"], default=d.up, help="up axis of the mesh file")
    parser.add_argument("--views", type=int, default=d.views, help="cameras on a Fibonacci sphere")
    parser.add_argument("--resolution", type=int, default=d.resolution, help="image width = height, pixels")
    parser.add_argument("--lighting", choices=["points", "flash", "env"], default=d.lighting,
                        help="two point lights per camera (the paper's layout), one at each camera (a flash) "
                             "or an environment map")
    parser.add_argument("--env", dest="environment", default=d.environment,
                        help="HDR environment map, or 'sky' for the procedural sky")
    parser.add_argument("--env-strength", type=float, default=d.env_strength)
    parser.add_argument("--env-rotation", dest="env_rotation_deg", type=float, default=d.env_rotation_deg,
                        help="Z rotation of the environment, degrees")
    parser.add_argument("--light-intensity", type=float, default=d.light_intensity,
                        help="W/sr per point light (0 = automatic)")
    parser.add_argument("--cornell", action="store_true", help="surround the cameras with a Cornell-style room")
    parser.add_argument("--albedo", default="pattern", help="'pattern' or an RGB triple 'r,g,b'")
    parser.add_argument("--specular", type=float, default=d.specular)
    parser.add_argument("--roughness", type=float, default=d.roughness)
    parser.add_argument("--spp", type=int, default=d.spp, help="samples per pixel")
    parser.add_argument("--max-depth", type=int, default=d.max_depth, help="path length (2 = direct light only)")
    parser.add_argument("--held-out", type=int, default=d.held_out, help="held-out (and relit) views")
    parser.add_argument("--relit-env", dest="relit_environment", default=d.relit_environment,
                        help="environment for relit ground truth views ('sky2' = procedural)")
    parser.add_argument("--exposure-drift", type=float, default=d.exposure_drift, metavar="STOPS",
                        help="a phone's auto-exposure: the frames' exposure swings by +-STOPS over the capture, "
                             "smoothly in frame index; the true gains go to gt/exposure.json and capture.json "
                             "marks the frames as auto-exposed (reconstruct --exposure auto fits them)")
    parser.add_argument("--white-balance-drift", type=float, default=d.white_balance_drift, metavar="STOPS",
                        help="a white-balance drift with it: colour temperature (red against blue) and tint (green against both) each swing by +-STOPS")
    parser.add_argument("--format", dest="image_format", choices=["exr", "png"], default=d.image_format)
    parser.add_argument("--seed", type=int, default=d.seed)
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")


def spec_from_args(args) -> SynthSpec:
    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(SynthSpec) if hasattr(args, f.name)}
    for flag, key in (("--exposure-drift", "exposure_drift"), ("--white-balance-drift", "white_balance_drift")):
        value = values.get(key, 0.0)
        require(math.isfinite(value) and 0.0 <= value <= MAX_DRIFT_STOPS, None, f"{flag} is {value:g}",
                f"give 0 to {MAX_DRIFT_STOPS:g} stops (the fit's gains stay within 1/4 to 4)")
    if values.get("albedo") != "pattern":
        values["albedo"] = [float(x) for x in str(values["albedo"]).split(",")]
    return SynthSpec(**values)


def run(args) -> int:
    write_synthetic_capture(spec_from_args(args), args.out, Emitter(), args.overwrite, args.variant)
    return 0
