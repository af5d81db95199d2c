"""Budget against wall clock: a time-budgeted run's whole wall time, its first geometry step, what
ran before that step, and its F1, on the paper's dragon or on a given capture.

``python -m backend bench budget [--minutes 2,5] [--init colmap|carve] [--capture CAPTURE]
[--first-step] [--repeat N]`` synthesises ``bench geometry``'s dragon capture (32 views at
128 px, the paper's point lights), or takes ``--capture``, and runs ``reconstruct CAPTURE
--init INIT --time-budget B`` with every other default for each budget ``B``, as a child process
timed from its start to its exit; ``--repeat`` runs each budget that many times in a row (the
later runs find what the first cached beside the capture). Each row: the budget, the wall
seconds and their excess over the budget (the target: at most 10 s), the time of the first
geometry step (the ``stage`` event of level 0, event times counting from the command's start),
what ran before it (``before_first_step``), the preset the budget chose, and, with a true mesh,
F1@0.01 and Chamfer-L1 against it. ``--first-step`` stops each run (``RUN/STOP``) once its first
geometry step has begun: rows of the time before the first step only. Writes the ``budget``
record (``first_step`` with ``--first-step``)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..capture.load import load_capture
from ..geometry.mesh import load_mesh, save_mesh
from ..metrics.evaluate import evaluate
from ..synth.capture import Y_UP_TO_Z_UP
from . import _launch, _records
from .geometry import DRAGON, dragon_capture


def add_arguments(parser) -> None:
    parser.add_argument("--minutes", default="2", help="comma-separated time budgets (default: %(default)s)")
    parser.add_argument("--init", default=None,
                        help="colmap (the authors' COLMAP mesh, the dragon's default), carve (a capture's default) "
                             "or any --init of reconstruct")
    parser.add_argument("--capture", type=Path, default=None, help="a capture folder instead of the dragon")
    parser.add_argument("--first-step", action="store_true",
                        help="stop each run once its first geometry step has begun")
    parser.add_argument("--repeat", type=int, default=1, help="runs per budget, in a row (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=Path("bench_budget"), help="folder for the capture and runs")
    parser.add_argument("--data", type=Path, default=DRAGON, help="folder with dragon.obj and colmap_dragon.obj")


def first_step(events: list[dict]) -> float | None:
    """Seconds from the command's start to its first geometry step (the event times count from it)."""
    return next((float(e["time"]) for e in events if e.get("event") == "stage" and e.get("stage") == "geometry"), None)


def before_first_step(events: list[dict]) -> dict[str, float]:
    """What ran before the first geometry step, in seconds from the events: ``start`` (the
    command's start to its first event: imports, the capture's loading), ``init`` (the initial
    mesh and material, up to the first effects decision), each part of that decision
    (``effects:bounces``, ``effects:self_shadowing``, ``effects:highlights``, ``effects:costs``,
    ``effects:other``; ``effects:cached`` when it came from the capture's cache) and ``rest``
    (up to the step)."""
    step = first_step(events)
    if step is None:
        return {}
    before = [e for e in events if float(e.get("time") or 0.0) <= step]
    out: dict[str, float] = {}
    if before:
        out["start"] = float(before[0].get("time") or 0.0)
    init = next((float(e["time"]) for e in before if e.get("event") == "stage" and e.get("stage") == "init"), None)
    decision = next((e for e in before if e.get("event") == "effects"), None)
    end = step
    if init is not None and decision is not None:
        seconds = float(decision.get("seconds") or 0.0)
        out["init"] = float(decision["time"]) - seconds - init
        parts = dict((decision.get("measured") or {}).get("seconds") or {})
        if (decision.get("measured") or {}).get("cache") == "hit":
            parts = {"cached": seconds}
        for name, value in parts.items():
            out[f"effects:{name}"] = float(value)
        out["effects:other"] = max(seconds - sum(parts.values()), 0.0)
        end = float(decision["time"])
        out["rest"] = step - end
    elif init is not None:
        out["init"] = step - init
    return {k: round(v, 2) for k, v in out.items()}


def _events(folder: Path) -> list[dict]:
    path = folder / "events.jsonl"
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _stopped_at_first_step(argv: list[str], out: Path, log: Path, timeout: float = 900.0) -> float:
    """Run ``argv`` until its first geometry step has begun, then ask it to stop; its wall seconds."""
    start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as f:
        child = _launch.popen(argv, stdout=f, stderr=f)
        try:
            while child.poll() is None and time.perf_counter() - start < timeout:
                if first_step(_events(out)) is not None:
                    (out / "STOP").touch()
                    break
                time.sleep(0.2)
            child.wait(timeout=max(timeout - (time.perf_counter() - start), 1.0))
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
    return time.perf_counter() - start


def run(args) -> int:
    if args.capture is None:
        capture = dragon_capture(args.out, args.data)
        init = args.init or "colmap"
        name = "the dragon"
        if init == "colmap":
            init = str(args.out / "colmap_dragon_zup.ply")
            save_mesh(init, load_mesh(args.data / "colmap_dragon.obj").transformed(Y_UP_TO_Z_UP))
    else:
        capture, init, name = args.capture, args.init or "carve", str(args.capture.name)
    truth = load_capture(capture).ground_truth or {}
    rows = []
    print(f"{'budget min':>10} {'wall s':>8} {'over s':>7} {'first step s':>12} {'preset':>8} {'F1@0.01':>8} "
          f"{'Chamfer':>8}  before the first step (s)")
    for minutes in [float(m) for m in args.minutes.split(",") if m.strip()]:
        for repeat in range(max(1, args.repeat)):
            tag = f"run_{minutes:g}" + (f"_{repeat + 1}" if args.repeat > 1 else "")
            out = args.out / tag
            argv = _launch.backend("reconstruct", capture, "--out", out, "--overwrite", "--init", init,
                                   "--time-budget", minutes)
            if args.first_step:
                seconds = _stopped_at_first_step(argv, out, args.out / f"{tag}.log")
            else:
                seconds = _launch.run(argv, log=args.out / f"{tag}.log", what="reconstruct").seconds
            events = _events(out)
            preset = next((e.get("preset") for e in events if e.get("event") == "preset"), None)
            metrics = (evaluate(out, capture, samples=100_000)["geometry"]
                       if truth.get("mesh") and not args.first_step else None)
            parts = before_first_step(events)
            row = {"budget min": minutes, "run": repeat + 1, "wall s": round(seconds, 1),
                   "over s": None if args.first_step else round(seconds - 60 * minutes, 1),
                   "first step s": first_step(events), "preset": preset,
                   "F1@0.01": None if metrics is None else round(metrics["f1@0.01"], 2),
                   "Chamfer-L1": None if metrics is None else round(metrics["chamfer_l1"], 5),
                   "before first step": ", ".join(f"{k} {v:g}" for k, v in parts.items() if v >= 0.05)}
            rows.append(row)
            print(f"{minutes:10g} {row['wall s']:8.1f} {row['over s'] or 0:7.1f} {row['first step s'] or 0:12.1f} "
                  f"{preset or '-':>8} {row['F1@0.01'] or 0:8.2f} {row['Chamfer-L1'] or 0:8.5f}  "
                  f"{row['before first step']}", flush=True)
    what = "the COLMAP mesh" if init.endswith("colmap_dragon_zup.ply") else f"--init {init}"
    command = f"python -m backend bench budget --minutes {args.minutes}"
    command += f" --capture {args.capture}" if args.capture is not None else ""
    command += f" --init {args.init}" if args.init else ""
    command += " --first-step" if args.first_step else ""
    command += f" --repeat {args.repeat}" if args.repeat > 1 else ""
    if args.first_step:
        _records.write_record(
            "first_step", title="Time to the first geometry step",
            context=(f"{name} from {what}, defaults and a time budget, stopped once the first geometry step has "
                     "begun; runs in a row on one capture (the later ones find its cached probes)"),
            rows=rows, show=["budget min", "run", "first step s", "preset", "before first step"], command=command)
    else:
        _records.write_record(
            "budget", title="Budget against wall clock",
            context=f"{name} from {what}, defaults and a time budget: the command's wall time, its first step",
            rows=rows, show=["budget min", "run", "wall s", "over s", "first step s", "preset", "F1@0.01",
                             "before first step"], command=command)
    return 0
