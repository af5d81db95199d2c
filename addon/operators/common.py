"""Helpers shared by the operators."""

from pathlib import Path

import bpy

from ..io.errors import require


def abspath(path: str) -> Path:
    return Path(bpy.path.abspath(path)).resolve() if path else Path()


def capture_dir(context, override: str = "", must_exist: bool = True) -> Path:
    """The capture folder: ``override`` if given, else the scene's."""
    chosen = override or context.scene.sft.capture_dir
    require(bool(chosen), None, "no capture folder is set",
            "import a video or cameras first, or set the capture folder in the Capture panel")
    path = abspath(chosen)
    if must_exist:
        require(path.is_dir(), path, "capture folder not found", "choose an existing folder")
    return path


RUNNING = {"install": "the backend is being installed", "import": "cameras are being imported",
           "solve": "the cameras are being solved: wait for it or cancel it",
           "reconstruct": "a reconstruction is running: wait for it or cancel it",
           "plan": "Plan is measuring the capture's step costs and accuracy: wait for it or cancel it",
           "video": "a video is being imported: wait for it or cancel it",
           "masks": "masks are being imported: wait for it or cancel it",
           "preview": "a relit preview is rendering: wait for it or cancel it",
           "export": "the glTF export is baking: wait for it or cancel it"}


def idle(cls, *kinds: str) -> bool:
    """poll(): False, with the reason, while a job of one of ``kinds`` runs."""
    from .. import jobs

    for kind in kinds:
        job = jobs.ACTIVE.get(kind)
        if job is not None and job.running:
            cls.poll_message_set(RUNNING[kind])
            return False
    return True


def has_backend(cls, context) -> bool:
    """poll(): False, with the fix, until some backend interpreter is set up."""
    from ..preferences import backend_ready

    if not backend_ready(context):
        cls.poll_message_set("no backend: press Install Backend in the add-on preferences")
        return False
    return True


def poll_reconstruction(cls, context, needs_capture: bool = False) -> bool:
    """Operators on the reconstructed mesh: grey them out (with the reason) until it exists."""
    from ..scene_mesh import OBJECT_NAME

    obj = bpy.data.objects.get(OBJECT_NAME)
    if obj is None or obj.type != "MESH" or not obj.data.polygons:
        cls.poll_message_set("no reconstruction yet: run Reconstruct first")
        return False
    if needs_capture and not context.scene.sft.capture_dir:
        cls.poll_message_set("no capture folder: import a video or cameras first")
        return False
    return True


def fail(operator, err) -> set[str]:
    operator.report({"ERROR"}, str(err))
    return {"CANCELLED"}


def stopped(operator, job, what: str) -> set[str]:
    """The report of a job that did not end "done" ("WHAT failed/cancelled: why"): an error when
    it failed, a warning when it was cancelled."""
    operator.report({"ERROR"} if job.state.status == "failed" else {"WARNING"},
                    f"{what} {job.state.status}: {job.state.message}")
    return {"CANCELLED"}
