"""What the panels and polls know of the files on disk, cached: ``draw()`` and ``poll()``
run on every redraw, so they read this and never the disk.

:func:`refresh` reads the capture folder, the run folder and the preset calibration once
and stores the answer; it runs when something may have changed them: the capture or run
folder setting changes (their update callbacks), a job ends (:data:`jobs.LISTENERS`), a
file is opened (``load_post``), and, in the UI, on a slow timer that catches changes made
outside Blender (redrawing only when the answer changed). A scene whose folders have no
cached answer yet reads as empty until the next refresh, which it schedules."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import bpy

from . import jobs
from .io import exposure_report, frames, preset_file

POLL_SECONDS = 2.0


@dataclass(frozen=True)
class Facts:
    """The files of one (capture folder, run folder) pair."""

    key: tuple[str, str] = ("", "")
    has_manifest: bool = False  # frames.json: an imported video
    has_capture_json: bool = False  # capture.json: cameras
    frames: int = 0  # images/*.png
    masks: int = 0  # masks/*.png
    has_masks_dir: bool = False
    has_materials: bool = False  # materials/*.png
    point_lights: int = 0  # the point lights capture.json gives its frames
    resumable: bool = False  # Resume can continue the run folder
    exposure: str = ""  # the finished run's per-frame gains in words (io.exposure_report), "" without
    calibration: dict = field(default_factory=dict, compare=False)  # backend/presets.json


EMPTY = Facts()
_CACHE: dict[tuple[str, str], Facts] = {}
_CALIBRATION: list[dict] = []  # [the preset calibration], read once per refresh of the calibration


def _key(scene) -> tuple[str, str]:
    sft = scene.sft  # normalised by string only: resolving links would touch the disk
    return tuple(os.path.normpath(bpy.path.abspath(p)) if p else "" for p in (sft.capture_dir, sft.run_dir))


def calibration() -> dict:
    """The preset calibration file's contents (read once; :func:`refresh` with
    ``calibration=True`` reads it again)."""
    if not _CALIBRATION:
        _CALIBRATION.append(preset_file.calibration())
    return _CALIBRATION[0]


def _count(folder: Path) -> int:
    try:
        return sum(1 for p in folder.iterdir() if p.suffix.lower() == ".png")
    except OSError:
        return 0


def _point_lights(path: Path) -> int:
    try:
        doc = json.loads(path.read_text())
        return sum(len(f.get("lights") or []) for f in doc.get("frames") or [] if isinstance(f, dict))
    except (OSError, ValueError, AttributeError, TypeError):
        return 0


def read(key: tuple[str, str]) -> Facts:
    """Read the facts of ``key`` from disk (the only place that does)."""
    from .operators.reconstruct import resumable  # the operators import this module: not at the top

    capture, run = (Path(p) if p else None for p in key)
    if capture is None:
        return Facts(key, resumable=bool(run) and resumable(str(run)), calibration=calibration(),
                     exposure=exposure_report.read(run) if run else "")
    capture_json = capture / "capture.json"
    return Facts(key, has_manifest=(capture / frames.MANIFEST).is_file(), has_capture_json=capture_json.is_file(),
                 frames=_count(capture / frames.IMAGES), masks=_count(capture / frames.MASKS),
                 has_masks_dir=(capture / frames.MASKS).is_dir(), has_materials=_count(capture / frames.MATERIALS) > 0,
                 point_lights=_point_lights(capture_json), resumable=bool(run) and resumable(str(run)),
                 calibration=calibration(), exposure=exposure_report.read(run) if run else "")


def refresh(scene=None, calibration_too: bool = False) -> bool:
    """Read the facts of ``scene``'s folders (the context's scene by default) again; True
    when they changed."""
    scene = scene or bpy.context.scene
    if scene is None or not hasattr(scene, "sft"):
        return False
    if calibration_too:
        _CALIBRATION.clear()
    key = _key(scene)
    new = read(key)
    old = _CACHE.get(key)
    _CACHE.clear()  # one scene is shown at a time: older folders' answers go
    _CACHE[key] = new
    return old != new


def facts(scene) -> Facts:
    """The cached facts of ``scene``'s folders; never reads a file."""
    key = _key(scene)
    found = _CACHE.get(key)
    if found is None:
        _schedule()
        return Facts(key, calibration=_CALIBRATION[0] if _CALIBRATION else {})
    return found


def _redraw() -> None:
    for window in getattr(bpy.context.window_manager, "windows", []):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def _tick() -> float | None:
    if refresh():
        _redraw()
    return POLL_SECONDS


def _once() -> None:
    if refresh():
        _redraw()


def _schedule() -> None:
    if not bpy.app.background and not bpy.app.timers.is_registered(_once):
        bpy.app.timers.register(_once, first_interval=0.0)


def on_setting_changed(_settings, context) -> None:
    """Update callback of the capture and run folder settings."""
    refresh(context.scene)


def on_job_ended(context, _job) -> None:
    refresh(getattr(context, "scene", None))


@bpy.app.handlers.persistent
def _on_load(*_args) -> None:
    refresh()


def register() -> None:
    jobs.LISTENERS.append(on_job_ended)
    bpy.app.handlers.load_post.append(_on_load)
    if not bpy.app.background:
        bpy.app.timers.register(_tick, first_interval=POLL_SECONDS, persistent=True)


def unregister() -> None:
    if on_job_ended in jobs.LISTENERS:
        jobs.LISTENERS.remove(on_job_ended)
    if _on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_on_load)
    for timer in (_tick, _once):
        if bpy.app.timers.is_registered(timer):
            bpy.app.timers.unregister(timer)
    _CACHE.clear()
    _CALIBRATION.clear()
