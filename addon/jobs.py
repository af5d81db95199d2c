"""Long work inside Blender: a job, its state, and what reaches the scene.

:meth:`Job.step` is the single update function: a modal timer calls it in the UI and the
headless path calls it in a loop (timers never fire in background mode). Three kinds:

- :class:`Job`: a child process speaking the JSON-lines protocol (the backend, or a
  background Blender running ``addon/worker.py``), read without blocking;
- :class:`TaskJob`: work that must run in Blender's own process (bpy data), cut into
  chunks by a generator, one chunk per step;
- :class:`ReconstructJob`: a backend run whose newest snapshot streams into the
  "Reconstruction" object."""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path
from typing import Callable, Iterator

import bpy

from . import accuracy_curve, scene_mesh
from .io import interpreter
from .io.errors import AddonInputError
from .io.ply import read_display_mesh
from .io.process import BackendProcess
from .io.progress import RunState

ACTIVE: dict[str, "Job"] = {}  # kind ("reconstruct", "solve", "video", ...) -> the job the panel shows
LISTENERS: list[Callable] = []  # called with (context, job) when a job ends: cached panel state refreshes


class Job:
    """A backend command running in the background, with its :class:`RunState`."""

    def __init__(self, python: str, args: list[str], run_dir: Path | None = None, kind: str = "job",
                 root: Path = interpreter.PACKAGE_DIR, argv: list[str] | None = None):
        self.kind = kind
        self.state = RunState()
        self.run_dir = run_dir
        self.process = BackendProcess(python, args, run_dir, root, argv=argv)
        self._settled = False
        ACTIVE[kind] = self

    @property
    def running(self) -> bool:
        return not self.process.finished

    def stop(self) -> None:
        self.process.request_stop()
        self.state.stopping()

    def step(self, context) -> bool:
        """Read new events and update the scene; False once the process has finished."""
        events = self.process.poll()
        for event in events:
            self.state.update(event)
        self.on_events(context, events)
        if not self.process.finished:
            return True
        if not self._settled:
            self._settled = True
            code = self.process.returncode
            if self.process.stop_requested_at is not None and code not in (0, 2):
                code = 130  # stopped by a signal (a worker, not the backend, dies of it): a cancel
            self.state.finish(code, self.process.log_tail(6).replace("\n", " | "))
            self.on_finish(context)
            _ended(context, self)
        return False

    def on_events(self, context, events: list[dict]) -> None:
        pass

    def on_finish(self, context) -> None:
        pass

    def run_blocking(self, context, interval: float = 0.1) -> None:
        """The headless path: drive :meth:`step` until the process ends."""
        while self.step(context):
            time.sleep(interval)


WORKER = interpreter.PACKAGE_DIR / "addon" / "worker.py"


def worker_argv(args: list[str]) -> list[str]:
    """The command line of ``addon/worker.py``: a background Blender (this Blender's own
    program), or this interpreter where Blender is the bpy module (it has no program)."""
    binary = bpy.app.binary_path
    if binary and Path(binary).is_file() and Path(sys.executable).resolve() != Path(binary).resolve():
        return [binary, "--background", "--python-exit-code", "1", "--python", str(WORKER), "--", *args]
    return [sys.executable, str(WORKER), *args]


class WorkerJob(Job):
    """``addon/worker.py`` in a child Blender: Cycles renders and bakes that would
    otherwise hold Blender's UI. ``folder`` is the worker's scratch folder (its input
    .blend and its output); it goes once the job has ended and :meth:`cleanup` is called
    (the operator moves the result out first), at once when the job did not succeed."""

    def __init__(self, args: list[str], kind: str, folder: Path):
        self.folder = Path(folder)
        super().__init__(sys.executable, [], None, kind=kind, argv=worker_argv(args))

    def on_finish(self, context) -> None:
        if self.state.status == "cancelled":
            self.state.message = "nothing was changed"
        if self.state.status != "done":
            self.cleanup()

    def cleanup(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def _ended(context, job) -> None:
    for listener in LISTENERS:
        listener(context, job)


class TaskJob:
    """Work in Blender's own process, cut into chunks: ``task`` is a generator that yields
    a progress event (``{"fraction": ..., "stage": ...}``) after each chunk and returns the
    result. :meth:`step` runs one chunk; a stop closes the generator at its next yield (its
    ``finally`` clauses undo what it had begun), so a cancelled task leaves nothing behind.
    An :class:`AddonInputError` it raises fails the job with that one line."""

    def __init__(self, task: Iterator[dict], kind: str):
        self.kind = kind
        self.state = RunState()
        self.task = task
        self.result = None
        self.error: AddonInputError | None = None
        self._finished = self._stop = False
        ACTIVE[kind] = self

    @property
    def running(self) -> bool:
        return not self._finished

    def stop(self) -> None:
        self._stop = True
        self.state.stopping()

    def step(self, context) -> bool:
        """Run one chunk; False once the task has ended (done, failed or cancelled)."""
        if self._finished:
            return False
        if self._stop:
            self.task.close()
            self.state.update({"event": "cancelled"})
            self.state.message = "nothing was changed"
            return self._end(context, 130)
        try:
            event = next(self.task)
        except StopIteration as done:
            self.result = done.value
            self.state.update({"event": "done"})
            return self._end(context, 0)
        except AddonInputError as err:
            self.error = err
            self.state.update({"event": "error", "message": str(err)})
            return self._end(context, 2)
        self.state.update({"event": "progress", **event})
        return True

    def _end(self, context, code: int) -> bool:
        self._finished = True
        self.state.finish(code)
        _ended(context, self)
        return False

    def run_blocking(self, context, interval: float = 0.0) -> None:
        while self.step(context):
            if interval:
                time.sleep(interval)


class ReconstructJob(Job):
    """``python -m backend reconstruct``; the newest snapshot streams into the scene."""

    def __init__(self, python: str, args: list[str], run_dir: Path, object_name: str,
                 root: Path = interpreter.PACKAGE_DIR):
        self.object_name = object_name
        self.applied: str | None = None  # the snapshot mesh now in the scene
        self.applied_stamp: int | None = None  # its file's mtime: material stages rewrite one name
        self.apply_seconds: list[float] = []  # main-thread cost of each update
        super().__init__(python, args, run_dir, "reconstruct", root)
        accuracy_curve.clear()  # the curve shown is this run's

    def on_events(self, context, events):
        if any(e.get("event") == "snapshot" for e in events):
            self.apply_latest(context)
        if any(e.get("event") == "accuracy" for e in events):
            accuracy_curve.show(self.run_dir)  # the backend redrew RUN/accuracy_time.png before the event

    def on_finish(self, context):
        self.apply_latest(context)
        if self.state.accuracy:
            accuracy_curve.show(self.run_dir)

    def apply_latest(self, context) -> bool:
        """Show the newest snapshot if it is not shown yet; True when the scene changed."""
        path = latest_snapshot(self.run_dir)
        try:
            stamp = path.stat().st_mtime_ns if path is not None else None
        except OSError:
            return False  # superseded and removed meanwhile: the next step reads the newer one
        if path is None or (str(path), stamp) == (self.applied, self.applied_stamp):
            return False
        start = time.perf_counter()
        if not show_snapshot(context, path, self.object_name):
            return False
        self.applied, self.applied_stamp = str(path), stamp
        self.apply_seconds.append(time.perf_counter() - start)
        return True


def latest_snapshot(run_dir: Path) -> Path | None:
    """The mesh ``snapshot.json`` names (it is replaced only after that mesh is complete)."""
    try:
        doc = json.loads((Path(run_dir) / "snapshot.json").read_text())
    except (OSError, ValueError):
        return None
    return Path(run_dir) / doc["mesh"] if isinstance(doc, dict) and doc.get("mesh") else None


def show_snapshot(context, path: Path, object_name: str = scene_mesh.OBJECT_NAME) -> bool:
    """Write a display mesh into the object; False when the file cannot be read."""
    try:
        mesh = read_display_mesh(path)
    except AddonInputError:
        return False
    obj = scene_mesh.reconstruction_object(context, object_name)
    scene_mesh.apply_display_mesh(obj, mesh)
    obj[scene_mesh.SOURCE_PROPERTY] = str(Path(path).resolve())
    return True


def tag_redraw(context) -> None:
    """Redraw the 3D views so the sidebar shows the new state."""
    for window in getattr(context.window_manager, "windows", []):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def _drain() -> float | None:
    """Timer: keep reading stopped jobs' pipes until their processes exit."""
    running = [job for job in ACTIVE.values() if job.running and isinstance(job, Job)]
    for job in running:
        job.process.poll()
        if isinstance(job, WorkerJob) and job.process.finished:
            job.cleanup()  # nobody takes its result any more
    return 0.2 if running else None


@bpy.app.handlers.persistent
def stop_on_load(*_args) -> None:
    """Another file is opening (its modal operators end): stop running jobs cleanly and
    forget finished ones (their status belongs to the old file)."""
    for kind in [kind for kind, job in ACTIVE.items() if not job.running]:
        del ACTIVE[kind]
    for job in ACTIVE.values():
        stop_unattended(job)


def stop_unattended(job) -> None:
    """Stop a job nobody steps any more; a timer reads its pipes until the process exits (a
    task's generator is closed at once: its clean-up runs now)."""
    job.stop()
    if isinstance(job, TaskJob):
        job.step(bpy.context)
        return
    if not bpy.app.timers.is_registered(_drain):
        bpy.app.timers.register(_drain, first_interval=0.2)


def register() -> None:
    bpy.app.handlers.load_pre.append(stop_on_load)


def unregister() -> None:
    """The add-on is disabled or Blender quits: end every backend process now."""
    if stop_on_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(stop_on_load)
    if bpy.app.timers.is_registered(_drain):
        bpy.app.timers.unregister(_drain)
    for job in ACTIVE.values():
        if job.running and isinstance(job, Job):
            job.process.kill()
        elif job.running:
            job.task.close()
    ACTIVE.clear()
