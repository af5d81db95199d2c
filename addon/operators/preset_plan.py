"""Plan: what each quality preset will cost on the scene's capture, measured by the backend
(``reconstruct CAPTURE --plan``: a few timed steps, nothing run) as a background job; the
panel shows the line its ``plan`` event carries, one predicted time per preset."""

from pathlib import Path

import bpy

from .. import jobs
from ..io import interpreter
from ..io.errors import AddonInputError, require
from ..preferences import backend_python
from .common import capture_dir, has_backend, idle
from .modal import CancelJob, JobModal
from .reconstruct import method_args, reconstruct_args


class PlanJob(jobs.Job):
    """``reconstruct CAPTURE --out UNUSED --plan`` with the panel's settings: its ``plan`` event."""

    def __init__(self, python: str, args: list[str], root: Path = interpreter.PACKAGE_DIR):
        self.plan: dict | None = None
        self.args = list(args)  # the settings measured: a line for others is not shown
        super().__init__(python, args, None, kind="plan", root=root)

    def on_events(self, context, events):
        for event in events:
            if event.get("event") == "plan":
                self.plan = event


def plan_args(capture: Path, sft) -> list[str]:
    """The backend command line: the panel's method settings and extra arguments, ``--plan``
    (RUN is required by the command but nothing is written there)."""
    return reconstruct_args(capture, capture / "runs" / "plan", None, sft.extra_args, method_args(sft)) + ["--plan"]


def plan_summary(plan: dict) -> str:
    """The line the panel shows."""
    return f"{plan['line']} on this capture"


def _measured_now(context, job: PlanJob) -> bool:
    """Whether the job measured the scene's capture and settings as they are now."""
    try:
        return plan_args(capture_dir(context), context.scene.sft) == job.args
    except AddonInputError:
        return False


class SFT_OT_plan(JobModal, bpy.types.Operator):
    """Measure what a step costs on this capture and probe its accuracy (seconds), and predict
    each quality preset's time and held-out PSNR on it; nothing is reconstructed"""

    bl_idname = "sft.plan"
    bl_label = "Plan"

    job_kind = "plan"

    @classmethod
    def poll(cls, context):
        if not idle(cls, "plan", "reconstruct", "solve"):
            return False
        sft = context.scene.sft
        if not sft.capture_dir:
            cls.poll_message_set("import a capture first")
            return False
        return has_backend(cls, context)

    def start(self, context) -> jobs.Job:
        capture = capture_dir(context)
        require((capture / "capture.json").is_file(), capture, "the capture has no cameras yet",
                "solve the cameras (Solve Cameras) or import them first")
        sft = context.scene.sft
        sft.plan_text = "Measuring this capture's step costs and accuracy..."
        python = backend_python(context)
        try:
            return PlanJob(python, plan_args(capture, sft))
        except OSError as err:
            sft.plan_text = ""
            raise AddonInputError(python, f"cannot start the backend ({err.strerror})",
                                  "choose the backend Python in the add-on preferences") from err

    def finish(self, context, job: PlanJob):
        sft = context.scene.sft
        if job.plan is not None and not _measured_now(context, job):
            sft.plan_text = ""
            self.report({"WARNING"}, "Plan: the capture or the settings changed while it measured; press Plan again")
            return {"CANCELLED"}
        if job.plan is None:
            sft.plan_text = ""
            self.report({"ERROR"}, f"Plan {job.state.status}: {job.state.message}")
            return {"CANCELLED"}
        sft.plan_text = plan_summary(job.plan)
        self.report({"INFO"}, sft.plan_text)
        return {"FINISHED"}


class SFT_OT_plan_cancel(CancelJob, bpy.types.Operator):
    """Stop measuring"""

    bl_idname = "sft.plan_cancel"
    bl_label = "Cancel Plan"
    job_kind = "plan"


CLASSES = (SFT_OT_plan, SFT_OT_plan_cancel)
