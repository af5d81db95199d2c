"""The process handle (bpy-free): non-blocking event reading, clean stop, escalation,
crashes. The child is the scripted backend (scripted_backend/), which follows
docs/protocol.md with known timings; one test runs the real backend's `check`."""

from __future__ import annotations

import sys
import time

import pytest

from addon.io import interpreter, progress
from addon.io.process import BackendProcess, parse_event

from .conftest import SCRIPTED_BACKEND


def scripted(tmp_path, *options, **kwargs) -> BackendProcess:
    return BackendProcess(sys.executable, ["reconstruct", "capture", "--out", str(tmp_path / "run"), *options],
                          tmp_path / "run", root=SCRIPTED_BACKEND, **kwargs)


def test_parse_event():
    assert parse_event('{"event": "stage", "time": 0.1, "stage": "init"}') == {"event": "stage", "time": 0.1, "stage": "init"}
    for line in ["plain text", '{"no_event": 1}', "{broken", "[1, 2]", ""]:
        assert parse_event(line) is None


def test_events_arrive_while_running_and_poll_never_blocks(tmp_path):
    proc = scripted(tmp_path, "--steps", "8", "--delay", "0.15")
    seen_running, slowest = False, 0.0
    while not proc.finished:
        t = time.perf_counter()
        events = proc.poll()
        slowest = max(slowest, time.perf_counter() - t)
        if events and proc.returncode is None:
            seen_running = True
        time.sleep(0.02)
    kinds = [e["event"] for e in proc.events]
    assert seen_running, "events only arrived after the process ended"
    assert slowest < 0.05
    assert kinds[:2] == ["start", "stage"] and kinds[-1] == "done"
    assert kinds.count("progress") == 8 and kinds.count("snapshot") == 8
    assert proc.returncode == 0
    assert proc.log_tail(1) == "step 8"  # stderr is kept as log


def test_split_lines_and_log_text(tmp_path):
    proc = scripted(tmp_path, "--mode", "split-lines", "--steps", "3", "--delay", "0.05")
    proc.wait(timeout=30)
    assert [e["iteration"] for e in proc.events if e["event"] == "progress"] == [1, 2, 3]
    assert list(proc.log).count("plain log text") == 3


def test_stop_file_cancels_cleanly(tmp_path):
    proc = scripted(tmp_path, "--steps", "1000", "--delay", "0.05")
    state = progress.RunState()
    while not any(e["event"] == "snapshot" for e in proc.events):
        for e in proc.poll():
            state.update(e)
        time.sleep(0.02)
    proc.request_stop()
    assert (tmp_path / "run" / "STOP").exists()
    for e in proc.wait(timeout=30):
        state.update(e)
    state.finish(proc.returncode)
    assert proc.returncode == 130 and state.status == progress.CANCELLED
    assert proc.events[-1]["event"] == "cancelled"
    assert (tmp_path / "run" / "snapshot.json").exists()


def test_stop_escalates_to_sigterm(tmp_path):
    proc = scripted(tmp_path, "--mode", "ignore-stop", "--delay", "0.05", grace_s=0.3, kill_s=5.0)
    while not proc.events:
        proc.poll()
        time.sleep(0.02)
    t = time.monotonic()
    proc.request_stop()
    proc.wait(timeout=10)
    assert proc.returncode == -15 and time.monotonic() - t < 3


def test_crash_keeps_log_tail(tmp_path):
    proc = scripted(tmp_path, "--mode", "crash", "--delay", "0.01")
    proc.wait(timeout=30)
    state = progress.RunState()
    for e in proc.events:
        state.update(e)
    state.finish(proc.returncode, proc.log_tail(3).replace("\n", " | "))
    assert proc.returncode == 1 and state.status == progress.FAILED
    assert "RuntimeError: scripted failure in the optimiser" in state.message


def test_bad_input_line(tmp_path):
    proc = scripted(tmp_path, "--mode", "bad-input")
    proc.wait(timeout=30)
    assert proc.returncode == 2 and "capture not found" in proc.log_tail(1)


def test_missing_interpreter_raises(tmp_path):
    with pytest.raises(OSError):
        BackendProcess(str(tmp_path / "no-python"), ["check"])


def test_real_backend_check_through_process_handle():
    proc = BackendProcess(sys.executable, ["check"], root=interpreter.PACKAGE_DIR)
    proc.wait(timeout=120)
    assert proc.returncode == 0 and '"ok": true' in proc.log_tail(1)
