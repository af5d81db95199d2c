"""Backend runs inside Blender: one process, its state, and what reaches the scene.

:meth:`Job.step` is the single update function: a modal timer calls it in the UI and the
headless path calls it in a loop (timers never fire in background mode). A reconstruction
job streams the newest snapshot mesh into the "Reconstruction" object."""

from __future__ import annotations

import json
import time
from pathlib import Path

import bpy

from . import accuracy_curve, scene_mesh
from .io import interpreter
from .io.errors import AddonInputError
from .io.ply import read_display_mesh
from .io.process import BackendProcess
from .io.progress import RunState

ACTIVE: dict[str, "Job"] = {}  # kind ("reconstruct", "solve") -> the job the panel shows


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
            self.state.finish(self.process.returncode, self.process.log_tail(6).replace("\n", " | "))
            self.on_finish(context)
        return False

    def on_events(self, context, events: list[dict]) -> None:
        pass

    def on_finish(self, context) -> None:
        pass

    def run_blocking(self, context, interval: float = 0.1) -> None:
        """The headless path: drive :meth:`step` until the process ends."""
        while self.step(context):
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
    running = [job for job in ACTIVE.values() if job.running]
    for job in running:
        job.process.poll()
    return 0.2 if running else None


@bpy.app.handlers.persistent
def stop_on_load(*_args) -> None:
    """Another file is opening (its modal operators end): stop running jobs cleanly and
    forget finished ones (their status belongs to the old file)."""
    for kind in [kind for kind, job in ACTIVE.items() if not job.running]:
        del ACTIVE[kind]
    for job in ACTIVE.values():
        stop_unattended(job)


def stop_unattended(job: Job) -> None:
    """Stop a job nobody steps any more; a timer reads its pipes until the process exits."""
    job.stop()
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
        if job.running:
            job.process.kill()
    ACTIVE.clear()
