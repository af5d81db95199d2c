"""Scripted ``python -m backend reconstruct CAPTURE --out RUN --mode MODE [--steps N]``.

It follows docs/protocol.md (events on stdout, atomic snapshots, STOP file / SIGTERM,
exit codes) with known timings and failures, so the add-on's process handle, event
parsing and snapshot streaming can be tested exactly; the real backend is tested in
test_end_to_end.py. Modes: ok, crash, bad-input, ignore-stop, split-lines, accuracy (every
step also redraws RUN/accuracy_time.png, one colour per step, and emits an ``accuracy``
event)."""

import argparse
import json
import os
import signal
import struct
import sys
import time
from pathlib import Path

START = time.perf_counter()


def emit(event, **fields):
    print(json.dumps({"event": event, "time": round(time.perf_counter() - START, 3), **fields}), flush=True)


def write_atomic(path: Path, data: bytes):
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def snapshot(run: Path, step: int):
    """A square of two triangles that grows and reddens with ``step``."""
    s = 1.0 + 0.1 * step
    verts = [(0, 0, 0), (s, 0, 0), (s, s, 0), (0, s, 0)]
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
              "property float z\nproperty float red\nproperty float green\nproperty float blue\n"
              "property float specular\nproperty float roughness\nelement face 2\n"
              "property list uchar int vertex_indices\nend_header\n").encode()
    body = b"".join(struct.pack("<8f", *v, min(1.0, 0.1 * step), 0.5, 0.2, 0.04, 0.5) for v in verts)
    body += struct.pack("<B3i", 3, 0, 1, 2) + struct.pack("<B3i", 3, 0, 2, 3)
    rel = f"snapshots/{step:06d}.ply"
    (run / "snapshots").mkdir(exist_ok=True)
    write_atomic(run / rel, header + body)
    write_atomic(run / "snapshot.json", json.dumps({"mesh": rel, "iteration": step, "stage": "geometry"}).encode())
    emit("snapshot", path=rel, iteration=step, faces=2, loss=1.0 / (step + 1))


def accuracy_figure(run: Path, step: int):
    """A 40 x 20 PNG whose red channel is 20 x step, then the ``accuracy`` event."""
    from PIL import Image  # only this mode draws

    tmp = run / ".accuracy_time.tmp.png"
    Image.new("RGB", (40, 20), (min(255, 20 * step), 100, 50)).save(tmp)
    os.replace(tmp, run / "accuracy_time.png")
    emit("accuracy", seconds=0.5 * step, psnr=15.0 + step, validation_loss=1.0 / step, level=0, stage="geometry",
         phase="level", why="every", views=2, scoring_seconds=0.01, figure="accuracy_time.png")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("command")
    p.add_argument("capture")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--mode", default="ok")
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--delay", type=float, default=0.05)
    a, _ = p.parse_known_args()
    if a.mode == "bad-input":
        print(f"error: {a.capture}: capture not found. Fix: give a capture folder", file=sys.stderr)
        return 2
    if a.mode != "ignore-stop":
        signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt()))
    run = a.out
    run.mkdir(parents=True, exist_ok=True)
    emit("start", run=str(run), capture=a.capture, settings={"steps": a.steps})
    emit("stage", stage="geometry", level=0, faces=2)
    step = 0
    try:
        while step < a.steps or a.mode == "ignore-stop":
            step += 1
            time.sleep(a.delay)
            line = json.dumps({"event": "progress", "time": 0.0, "stage": "geometry", "level": 0,
                               "iteration": step, "iterations": a.steps, "loss": 1.0 / step, "faces": 2,
                               "seconds": a.delay, "fraction": min(1.0, step / a.steps),
                               "eta_s": a.delay * max(0, a.steps - step)})
            if a.mode == "split-lines":  # one event in two writes, log text between events
                sys.stdout.write(line[:10])
                sys.stdout.flush()
                time.sleep(a.delay)
                sys.stdout.write(line[10:] + "\nplain log text\n")
                sys.stdout.flush()
            else:
                print(line, flush=True)
            print(f"step {step}", file=sys.stderr, flush=True)
            snapshot(run, step)
            if a.mode == "accuracy":
                accuracy_figure(run, step)
            if a.mode == "crash" and step == 2:
                raise RuntimeError("scripted failure in the optimiser")
            if a.mode != "ignore-stop" and (run / "STOP").exists():
                raise KeyboardInterrupt
    except KeyboardInterrupt:
        emit("cancelled", snapshot=f"snapshots/{step:06d}.ply")
        return 130
    next_level = {"level": 1, "size": 128, "psnr_gain_db": 1.5, "extrapolated": True} if a.mode == "accuracy" else None
    emit("done", result="result.ply", report="report.json", metrics={"f1": 0.5}, next_level=next_level)
    return 0


if __name__ == "__main__":
    sys.exit(main())
