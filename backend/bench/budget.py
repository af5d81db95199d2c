"""Budget against wall clock: a time-budgeted run's whole wall time, its first geometry step and its F1, on the paper's dragon.

``python -m backend bench budget [--minutes 2,5] [--init colmap|carve]`` synthesises
``bench geometry``'s dragon capture (32 views at 128 px, the paper's point lights) and runs
``reconstruct CAPTURE --init INIT --time-budget B`` with every other default for each budget
``B``, as a child process timed from its start to its exit. Each row: the budget, the wall
seconds and their excess over the budget (the target: at most 10 s), the time of the first
geometry step (the ``stage`` event of level 0), the preset the budget chose, and F1@0.01 and
Chamfer-L1 against the truth. Writes the ``budget`` record."""

from __future__ import annotations

import json
from pathlib import Path

from ..geometry.mesh import load_mesh, save_mesh
from ..metrics.evaluate import evaluate
from ..synth.capture import Y_UP_TO_Z_UP
from . import _launch, _records
from .geometry import DRAGON, dragon_capture


def add_arguments(parser) -> None:
    parser.add_argument("--minutes", default="2", help="comma-separated time budgets (default: %(default)s)")
    parser.add_argument("--init", choices=("colmap", "carve"), default="colmap",
                        help="the authors' COLMAP mesh (default) or the visual hull")
    parser.add_argument("--out", type=Path, default=Path("bench_budget"), help="folder for the capture and runs")
    parser.add_argument("--data", type=Path, default=DRAGON, help="folder with dragon.obj and colmap_dragon.obj")


def first_step(events: list[dict]) -> float | None:
    """Seconds from the command's start to its first geometry step (the event times count from it)."""
    return next((float(e["time"]) for e in events if e.get("event") == "stage" and e.get("stage") == "geometry"), None)


def run(args) -> int:
    capture = dragon_capture(args.out, args.data)
    init = "carve"
    if args.init == "colmap":
        init = str(args.out / "colmap_dragon_zup.ply")
        save_mesh(init, load_mesh(args.data / "colmap_dragon.obj").transformed(Y_UP_TO_Z_UP))
    rows = []
    print(f"{'budget min':>10} {'wall s':>8} {'over s':>7} {'first step s':>12} {'preset':>8} {'F1@0.01':>8} {'Chamfer':>8}")
    for minutes in [float(m) for m in args.minutes.split(",") if m.strip()]:
        out = args.out / f"run_{minutes:g}"
        child = _launch.run(_launch.backend("reconstruct", capture, "--out", out, "--overwrite", "--init", init,
                                            "--time-budget", minutes),
                            log=args.out / f"run_{minutes:g}.log", what="reconstruct")
        events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines() if line.strip()]
        preset = next((e.get("preset") for e in events if e.get("event") == "preset"), None)
        metrics = evaluate(out, capture, samples=100_000)["geometry"]
        row = {"budget min": minutes, "wall s": round(child.seconds, 1),
               "over s": round(child.seconds - 60 * minutes, 1), "first step s": first_step(events),
               "preset": preset, "F1@0.01": round(metrics["f1@0.01"], 2),
               "Chamfer-L1": round(metrics["chamfer_l1"], 5)}
        rows.append(row)
        print(f"{minutes:10g} {row['wall s']:8.1f} {row['over s']:7.1f} {row['first step s'] or 0:12.1f} "
              f"{preset or '-':>8} {row['F1@0.01']:8.2f} {row['Chamfer-L1']:8.5f}", flush=True)
    _records.write_record(
        "budget", title="Budget against wall clock",
        context=(f"the dragon from {'the COLMAP mesh' if args.init == 'colmap' else 'the visual hull'}, defaults and "
                 "a time budget: the command's wall time, its first step"),
        rows=rows, show=["budget min", "wall s", "over s", "first step s", "preset", "F1@0.01"], command=f"python -m backend bench budget --minutes {args.minutes} --init {args.init}")
    return 0
