"""Bad input and signals at the ``reconstruct`` command: an ``--out`` that is a file and frames
with no signal stop with one line (exit 2, nothing written); SIGTERM while a differentiable
render runs is a clean cancel (exit 130, no traceback, the last snapshot kept)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from backend.capture.images import read_rgba, write_image
from tests.helpers import REPO, run_cli

SMALL = json.dumps({"max_size": 32, "coarse_size": 32})


def test_out_naming_a_file_is_one_line_and_exit_2(tiny_capture, tmp_path):
    out = tmp_path / "run"
    out.write_text("not a folder")
    proc = run_cli("reconstruct", tiny_capture, "--out", out, "--iterations", 2, "--material", "constant")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "the run folder is a file" in lines[0] and str(out) in lines[0]
    assert out.read_text() == "not a folder"


def test_frames_with_no_signal_are_named_and_nothing_is_written(tiny_capture, tmp_path):
    capture = tmp_path / "capture"
    shutil.copytree(tiny_capture, capture)
    frames = json.loads((capture / "capture.json").read_text())["frames"]
    for frame in frames[:2]:
        path = capture / frame["image"]
        image, _ = read_rgba(path)
        write_image(path, np.zeros_like(image))
    out = tmp_path / "run"
    proc = run_cli("reconstruct", capture, "--out", out, "--iterations", 2, "--material", "constant")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "2 of 8 frames have no signal" in lines[0], lines
    assert all(Path(f["image"]).stem in lines[0] for f in frames[:2])
    assert not out.exists()


def _terminate_after(capture: Path, out: Path, event: str, delay: float) -> tuple[int, str, list[dict]]:
    """Start a run, send SIGTERM ``delay`` s after its first ``event`` event; (exit code, stderr, events)."""
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1", SFT_RECONSTRUCT_SETTINGS=SMALL)
    proc = subprocess.Popen([sys.executable, "-m", "backend", "reconstruct", str(capture), "--out", str(out),
                             "--iterations", "400", "--material", "constant"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
    try:
        for line in proc.stdout:
            if line.startswith("{") and json.loads(line).get("event") == event:
                break
        time.sleep(delay)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=300)
    finally:
        proc.kill()
    events = [json.loads(line) for line in (out / "events.jsonl").read_text().splitlines() if line.strip()]
    return proc.returncode, err, events


def test_sigterm_during_renders_is_a_clean_cancel(tiny_capture, tmp_path):
    """Steps render through Dr.Jit custom operations, which wrap an interrupt in a RuntimeError:
    at every point tried the run still ends as a cancel, keeping its snapshot."""
    for i, delay in enumerate((0.0, 0.35, 0.8, 1.7)):
        out = tmp_path / f"run{i}"
        rc, err, events = _terminate_after(tiny_capture, out, "snapshot", delay)
        assert rc == 130, (delay, err[-3000:])
        assert "Traceback" not in err, (delay, err[-3000:])
        names = [e["event"] for e in events]
        assert "error" not in names and names[-1] == "cancelled", (delay, names[-5:])
        snapshot = json.loads((out / "snapshot.json").read_text())
        assert (out / snapshot["mesh"]).is_file()
