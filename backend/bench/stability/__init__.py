"""Hard cases through the real reconstruction pipeline: every step finite and valid (table of cases).

``python -m backend bench stability [--quick] [--case NAME ...]`` runs ``reconstruct`` on
small synthetic captures that each have one hard property: extreme materials (roughness and
specular reflectance near 0 and 1), grazing or single views, views with the object masked
out, near-black frames, frames with NaN/Inf pixels, a 1e5 sun beside a dim sky, degenerate,
oversized or camera-enclosing initial meshes, 1 spp, a learning rate 100x too large (vertex
and material steps), mesh colors at r = 0 and 8, a mesh of 50k (``--quick``) or 500k faces,
an injected NaN gradient, a backend killed mid-write and resumed, a full disk. It also
checks the projective geometry gradient and the mesh-colors gradient against central finite
differences.

For each pipeline case every gradient evaluation is recorded (the loop's ``Objective`` is
wrapped, the real one does the work) and checked: loss, gradients, vertex positions and
material latents finite, material values in their ranges; every non-finite step skipped,
counted in report.json and announced by a warning; each level's mesh finite and, after
refinement, a closed manifold, and free of self-intersections after a re-mesh; the outputs
(result.ply, last snapshot) valid; no crash. ``--quick`` runs the tiny versions the tests
use (32 px, about a dozen steps, in this process); the default runs the longer versions,
each in its own process so that its peak memory is measured (the 500k-face case must stay
under 12 GB). Prints a table: case, steps run, non-finite or invalid steps caught, final
loss, peak memory, pass/fail; writes ``OUT/results.json``."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from .. import _records
from ... import fsio, variant
from ...errors import InputError
from .cases import case_names, guarded, isolated, run_case, table  # noqa: F401
from .checks import material_problems, mesh_checks, read_events, recorder, run_folder_problems  # noqa: F401
from .pipeline import Setup, config, pipeline_cases, reconstruct  # noqa: F401
from .results import GRADIENT_TOLERANCE, KNOWN, MEMORY_LIMIT_GB, REPO, Result, StepLog  # noqa: F401


def add_arguments(parser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="the tiny versions the tests run (32 px, a dozen steps, 50k-face case), in this process")
    parser.add_argument("--case", action="append", metavar="NAME", help="run only these cases (repeatable)")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "bench-stability",
                        help="work folder (replaced); results.json is written there")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")


def run(args) -> int:
    if args.variant:
        os.environ["SFT_VARIANT"] = args.variant
    variant.choose(args.variant)
    names = args.case or case_names(args.quick)
    for name in names:
        if name not in case_names(args.quick):
            raise InputError(None, f"no stability case '{name}'", f"choose from {', '.join(case_names(args.quick))}")
    out = Path(args.out)
    shutil.rmtree(out / "cases", ignore_errors=True)
    records = []
    for name in names:
        work = out / "cases" / name
        work.mkdir(parents=True, exist_ok=True)
        records.append(guarded(name, work, True) if args.quick else isolated(name, work, False))
        print(f"{name}: {'pass' if records[-1]['passed'] else 'FAIL'} ({records[-1]['seconds']:.1f} s)",
              file=sys.stderr, flush=True)
    fsio.write_json(out / "results.json", {"quick": args.quick, "cases": records}, indent=1)
    print(table(records))
    print("caught: steps the loop skipped and reported (a non-finite loss, gradient or vertex position, "
          "or a step that would put a camera inside the mesh)")
    passed = sum(r["passed"] for r in records)
    _records.write_record(
        "stability", title="Numerical stability", variant=variant.choose(args.variant),
        context="hard cases through the real pipeline (extreme materials and views, degenerate meshes, NaN gradients, "
                "a killed run, a full disk), each checked for finite values and valid meshes",
        rows=[{"case": r["case"], "passed": "yes" if r["passed"] else "no", "seconds": r.get("seconds")}
              for r in records], scalars={"passed": passed, "cases": len(records)},
        failed=[r["case"] for r in records if not r["passed"]], display="scalars" if passed == len(records) else None)
    print(f"\n{passed}/{len(records)} passed" + ("" if args.quick else "; peak GB per case, each in its own process")
          + (" (peak GB: this process so far)" if args.quick else ""))
    return 0 if passed == len(records) else 1
