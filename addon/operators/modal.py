"""The modal pattern shared by operators that run a backend job.

``invoke`` starts the job and reads its events on a window timer without blocking the UI;
``execute`` (scripts, background mode, where timers never fire) drives the same
:meth:`jobs.Job.step` in a loop until the job ends. A job stops on its panel's Cancel
button, or on Esc pressed while the mouse is over a 3D view's sidebar (where that button
is): an Esc meant for another editor (leaving a modal tool, closing a menu) passes through."""

import bpy

from .. import jobs
from ..io.errors import AddonInputError
from .common import fail

TIMER_SECONDS = 0.2


class JobModal:
    job_kind = "job"

    def status_text(self, job: jobs.Job) -> str:
        """The status bar's line while the job runs."""
        state = job.state
        return (f"{self.bl_label}: {state.headline()}  {state.fraction:.0%}  {state.eta_text()}"
                "  (Cancel in the sidebar, or Esc over it)")

    def _status(self, context, text: str | None) -> None:
        workspace = getattr(context, "workspace", None)
        if workspace is not None:
            workspace.status_text_set(text)

    def start(self, context) -> jobs.Job:
        raise NotImplementedError

    def finish(self, context, job: jobs.Job) -> set[str]:
        raise NotImplementedError

    def _begin(self, context):
        running = jobs.ACTIVE.get(self.job_kind)
        if running is not None and running.running:
            raise AddonInputError(None, f"a {self.job_kind} run is already in progress",
                                  "wait for it or cancel it")
        return self.start(context)

    def execute(self, context):
        try:
            job = self._begin(context)
        except AddonInputError as err:
            return fail(self, err)
        try:
            job.run_blocking(context)
        except KeyboardInterrupt:  # Ctrl-C in a headless run: stop cleanly, keep the snapshot
            job.stop()
            job.run_blocking(context)
        return self.finish(context, job)

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        return self.start_modal(context)

    def start_modal(self, context):
        """Start the job and follow it on a window timer (the UI stays responsive)."""
        try:
            self._job = self._begin(context)
        except AddonInputError as err:
            return fail(self, err)
        wm = context.window_manager
        self._timer = wm.event_timer_add(TIMER_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        self._status(context, self.status_text(self._job))
        jobs.tag_redraw(context)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS" and over_sidebar(context, event):
            self._job.stop()
            jobs.tag_redraw(context)
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._job.step(context):
            self._status(context, self.status_text(self._job))
            jobs.tag_redraw(context)
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        self._status(context, None)
        jobs.tag_redraw(context)
        return self.finish(context, self._job)

    def cancel(self, context):
        """Blender ends the operator (its window closes): stop the backend cleanly; the
        last snapshot stays on disk."""
        jobs.stop_unattended(self._job)
        self._status(context, None)


def over_sidebar(context, event) -> bool:
    """Whether the mouse is over the sidebar (UI region) of a 3D view in the event's window."""
    window = getattr(context, "window", None)
    screen = getattr(window, "screen", None)
    if screen is None:
        return False
    x, y = event.mouse_x, event.mouse_y
    return any(region.type == "UI" and region.x <= x < region.x + region.width
               and region.y <= y < region.y + region.height
               for area in screen.areas if area.type == "VIEW_3D" for region in area.regions)


class CancelJob:
    """A Cancel button for the job of kind ``job_kind``: a clean stop (the backend keeps what
    it had finished); greyed out while no such job runs."""

    job_kind = "job"

    @classmethod
    def poll(cls, context):
        job = jobs.ACTIVE.get(cls.job_kind)
        return job is not None and job.running

    def execute(self, context):
        jobs.ACTIVE[self.job_kind].stop()
        jobs.tag_redraw(context)
        return {"FINISHED"}


class SFT_OT_cancel_job(bpy.types.Operator):
    """Stop the running job of this kind (nothing it had not finished reaches the scene)"""

    bl_idname = "sft.cancel_job"
    bl_label = "Cancel"

    kind: bpy.props.StringProperty(name="Job", default="", options={"SKIP_SAVE"})

    @classmethod
    def poll(cls, context):
        return any(job.running for job in jobs.ACTIVE.values())

    def execute(self, context):
        job = jobs.ACTIVE.get(self.kind)
        if job is None or not job.running:
            self.report({"ERROR"}, f"no '{self.kind}' job is running")
            return {"CANCELLED"}
        job.stop()
        jobs.tag_redraw(context)
        return {"FINISHED"}


CLASSES = (SFT_OT_cancel_job,)
