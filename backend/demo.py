"""The demo: synthesise the built-in procedural object, reconstruct it, print the metrics.

Runs the same commands a user would (``synth``, ``reconstruct``, ``evaluate``) as
subprocesses and turns their JSON events into a short readable log (the ``demo`` command)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from .errors import InputError


def _follow(args: list[str], label: str) -> dict:
    """Run ``python -m backend ARGS``; print a line per stage and every few seconds; return the last event."""
    proc = subprocess.Popen([sys.executable, "-m", "backend", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, bufsize=1)
    last, last_print, stage = {}, 0.0, None
    for line in proc.stdout:
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            continue
        last = event
        kind = event.get("event")
        if kind == "stage" or (event.get("stage") and event.get("stage") != stage):
            stage = event.get("stage")
            print(f"[{label}] {event['time']:7.1f}s  stage {stage} level {event.get('level', '-')}"
                  f" faces {event.get('faces', '-')}", flush=True)
        elif kind == "progress" and time.monotonic() - last_print > 10:
            last_print = time.monotonic()
            loss = event.get("loss")
            print(f"[{label}] {event['time']:7.1f}s  {100 * (event.get('fraction') or 0):5.1f}%"
                  + (f"  loss {loss:.3g}" if loss is not None else "")
                  + (f"  faces {event['faces']}" if event.get("faces") else ""), flush=True)
        elif kind in ("warning", "error"):
            print(f"[{label}] {kind}: {event.get('message')}", flush=True)
    stderr = proc.stderr.read()
    if proc.wait() != 0:
        if proc.returncode == 2:
            raise InputError(None, stderr.strip().removeprefix("error: "))
        sys.stderr.write(stderr[-4000:])
        raise SystemExit(proc.returncode)
    return last


def demo(out: Path, minutes: float = 4.0, views: int = 24, resolution: int = 128) -> int:
    """Synthesise into OUT/capture (kept when it exists), reconstruct into OUT/run within
    ``minutes``, score it into OUT/evaluation.json and print the metrics. Returns 0; a failed step raises
    :class:`InputError` (bad input) or ``SystemExit`` (its exit code)."""
    out = Path(out).resolve()
    capture, run_dir = out / "capture", out / "run"
    if not (capture / "capture.json").is_file():
        _follow(["synth", "--out", str(capture), "--views", str(views), "--resolution",
                 str(resolution), "--held-out", "4", "--overwrite"], "synth")
    else:
        print(f"[synth] reusing {capture}")
    _follow(["reconstruct", str(capture), "--out", str(run_dir), "--preset", "balanced",
             "--material", "constant", "--time-budget", str(minutes), "--overwrite"], "reconstruct")
    report = out / "evaluation.json"
    proc = subprocess.run([sys.executable, "-m", "backend", "evaluate", str(run_dir), "--truth", str(capture),
                           "--out", str(report)], capture_output=True, text=True)
    if proc.returncode != 0:
        sys.stderr.write(proc.stderr[-4000:])
        raise SystemExit(proc.returncode)
    print(proc.stdout.rstrip())
    print(f"result:  {run_dir / 'result.ply'}\nreport:  {run_dir / 'report.json'}\nmetrics: {report}")
    return 0
