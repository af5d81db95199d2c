"""Process faults: the backend killed mid-write and resumed, a full disk."""

from __future__ import annotations

import contextlib
import json
import math
import os
import resource
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np

from ...geometry.mesh import load_mesh, save_mesh
from ...geometry.topology import inspect
from .. import _launch
from .checks import read_events, run_folder_problems, temporary_files
from .results import KNOWN, REPO, Result
from .scenes import lit_blob, sphere_init, torus_init


# -- process faults ------------------------------------------------------------------------------------------
def _reconstruct_args(capture: Path, run: Path, init: Path, faces: int, iterations: int) -> list[str]:
    return _launch.backend("reconstruct", capture, "--out", run, "--init", init, "--initial-faces", faces,
                           "--max-size", 32, "--coarse-size", 32, "--spp", 2, "--iterations", iterations,
                           "--max-levels", 2, "--material", KNOWN, "--remesh", "never")


def _kill_at_write(args: list[str], run: Path, after_snapshots: int, timeout: float = 300) -> bool:
    """Start the backend and SIGKILL it the moment it starts an atomic write (a new temporary
    file appears in the run folder) once ``after_snapshots`` snapshot events have come. False
    if it ended first."""
    proc = _launch.popen(args, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    snapshots = []
    reader = threading.Thread(target=lambda: snapshots.extend(line for line in proc.stdout if '"snapshot"' in line),
                              daemon=True)
    reader.start()
    old = set(temporary_files(run)) if run.exists() else set()
    deadline = time.monotonic() + timeout
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if len(snapshots) >= after_snapshots and run.exists() and set(temporary_files(run)) - old:
                proc.send_signal(signal.SIGKILL)
                return True
            time.sleep(0.0005)
        return False
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        reader.join(timeout=5)


def killed_mid_write(work: Path, quick: bool) -> Result:
    """The backend (``reconstruct`` with a mesh large enough that a snapshot takes a while to
    write) is killed with SIGKILL the moment it starts an atomic write: during its first
    snapshot, during a later one, and after resuming; after each kill every file in the run
    folder is whole (the last snapshot and the saved state load) and the run goes on with
    --resume (or starts over when no state was saved yet). The last resume must finish with
    a valid result."""
    start = time.perf_counter()
    result = Result("killed_mid_write")
    work = Path(work)
    capture = lit_blob(True).write(work / "capture")
    faces = 20_000 if quick else 200_000
    save_mesh(work / "init.ply", torus_init(faces)(quick))
    run = work / "run"
    iterations = 6 if quick else 20
    kills, mid_write, leftovers = 0, 0, 0
    for after_snapshots in (0, 1, 0) if quick else (0, 1, 0, 1, 0, 1):
        resume = (run / "state" / "state.json").exists()
        args = _reconstruct_args(capture, run, work / "init.ply", faces, iterations)
        if not _kill_at_write(args + (["--resume"] if resume else ["--overwrite"]), run, after_snapshots):
            result.notes.setdefault("finished_before_kill", 0)
            result.notes["finished_before_kill"] += 1
            continue
        kills += 1
        mid_write += len(temporary_files(run)) > leftovers  # a write was cut off
        leftovers = len(temporary_files(run))
        for problem in run_folder_problems(run):
            result.problems.append(f"after kill {kills}: {problem}")
    proc = _launch.run(_reconstruct_args(capture, run, work / "init.ply", faces, iterations)
                       + (["--resume"] if (run / "state" / "state.json").exists() else ["--overwrite"]),
                       cwd=REPO, timeout=600)
    result.notes.update(kills=kills, killed_during_a_write=mid_write, temporary_files_left=len(temporary_files(run)))
    result.check(kills >= 2 and mid_write >= 1, f"{kills} kills, {mid_write} during a write: too few to tell")
    if result.check(proc.returncode == 0, f"final run exited {proc.returncode}: {proc.stderr[-300:]}"):
        report = json.loads((run / "report.json").read_text())
        mesh = load_mesh(run / "result.ply")
        result.steps, result.caught = report["result"]["iterations"], report["skipped_steps"]
        result.final_loss = report["losses"][-1] if report["losses"] else None
        result.check(bool(np.all(np.isfinite(mesh.vertices))) and inspect(mesh).closed_manifold,
                     "resumed result not a finite closed manifold")
        result.check(result.final_loss is not None and math.isfinite(result.final_loss), "no finite final loss")
        stages = [e.get("stage") for e in read_events(run)]
        result.check(read_events(run)[-1]["event"] == "done" and "resume" in stages,
                     "the last run did not resume and finish")
    result.problems += run_folder_problems(run)
    result.seconds = round(time.perf_counter() - start, 1)
    return result


@contextlib.contextmanager
def quota_folder(path: Path, size_kb: int):
    """``path`` as a tmpfs of ``size_kb`` (a real full disk: ENOSPC); yields False where
    mounting is not permitted (the caller then limits file sizes instead: EFBIG)."""
    path.mkdir(parents=True, exist_ok=True)
    mounted = False
    if hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("mount"):
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(path)],
                                 capture_output=True).returncode == 0
    try:
        yield mounted
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(path)], capture_output=True)


def _limit_file_size(limit: int):
    def apply():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def _fill(path: Path) -> None:
    """Write zeros into ``path`` until the disk is full."""
    with contextlib.suppress(OSError), open(path, "wb") as f:
        while True:
            f.write(b"\0" * (64 << 10))
            f.flush()


def full_disk(work: Path, quick: bool) -> Result:
    """``reconstruct`` writing into a tiny quota folder: (a) too small for the first snapshot,
    (b) filled up by another file while the run is under way. Each must end with exit code 2
    and one line naming the file and the fix, leave no temporary file and nothing unreadable;
    (b), once space is freed, must resume to a valid result. Where mounting a tmpfs is not
    permitted, (a) runs with a file-size limit instead and (b) is left out."""
    start = time.perf_counter()
    result = Result("full_disk")
    work = Path(work)
    capture = lit_blob(True).write(work / "capture")
    save_mesh(work / "init.ply", sphere_init(0.7, 4)(quick))  # 5120 faces: a snapshot of about 150 KB
    for scenario, size_kb in (("too_small", 24), ("fills_up", 1024)):
        folder = work / scenario
        run = folder / "run"
        args = _reconstruct_args(capture, run, work / "init.ply", 5120, 400)
        with quota_folder(folder, size_kb) as mounted:
            if not mounted and scenario == "fills_up":
                result.notes[scenario] = "left out: mounting a tmpfs is not permitted here"
                continue
            proc = _launch.popen(args, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                 preexec_fn=None if mounted else _limit_file_size(size_kb << 10))
            out = ""
            if scenario == "fills_up":
                for line in proc.stdout:  # once the run is under way, fill the disk
                    out += line
                    if '"progress"' in line and '"geometry"' in line:
                        _fill(folder / "filler")
                        break
            more, err = proc.communicate(timeout=600)
            out += more
            lines = err.strip().splitlines()
            result.notes[scenario] = {"quota": f"tmpfs of {size_kb} KB" if mounted else f"files of {size_kb} KB at most",
                                      "exit": proc.returncode, "stderr": lines[-1] if lines else ""}
            result.check(proc.returncode == 2, f"{scenario}: exit code {proc.returncode}, expected 2: {err[-300:]}")
            result.check(len(lines) == 1 and lines[0].startswith("error: ") and "Fix:" in lines[0]
                         and ("no space" in lines[0] or "too large" in lines[0]),
                         f"{scenario}: not one clear line: {err[-300:]}")
            result.check(not temporary_files(run), f"{scenario}: temporary files left: {temporary_files(run)}")
            result.problems += [f"{scenario}: {p}" for p in run_folder_problems(run)]
            events = [json.loads(x) for x in out.splitlines() if x.startswith("{")]
            result.check(bool(events) and events[-1]["event"] == "error", f"{scenario}: the last event is not the error")
            result.steps += max((e.get("iteration") or 0 for e in events if e["event"] == "progress"), default=0)
            if scenario == "fills_up":
                (folder / "filler").unlink()
                done = json.loads((run / "state" / "state.json").read_text())["iteration"]
                resumed = _launch.run(_reconstruct_args(capture, run, work / "init.ply", 5120, done + 6)
                                      + ["--resume"], cwd=REPO, timeout=600)
                result.check(resumed.returncode == 0,
                             f"resume after freeing space: exit {resumed.returncode}: {resumed.stderr[-300:]}")
                result.problems += [f"after resume: {p}" for p in run_folder_problems(run)]
    result.seconds = round(time.perf_counter() - start, 1)
    return result


# -- the benchmark ----------------------------------------------------------------------------------------------
