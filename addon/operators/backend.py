"""The backend's interpreter: install one (a background job with progress and cancel), and
check it without freezing Blender."""

import json
import sys

import bpy

from .. import ROOT_PACKAGE, jobs
from ..io import interpreter
from ..io.errors import AddonInputError, require
from ..preferences import backend_python, installed_venv
from .common import idle, stopped
from .modal import CancelJob, JobModal


def _set_check_result(context, text: str) -> None:
    addon = context.preferences.addons.get(ROOT_PACKAGE)
    if addon and addon.preferences:
        addon.preferences.check_result = text


class SFT_OT_install_backend(JobModal, bpy.types.Operator):
    """Create a private Python environment in the extension's user folder and install the
    backend's pinned libraries into it (a 340 MB download, 1.1 GB on disk; needs the internet once).
    It is built beside the installed one, which it replaces only once it works"""

    bl_idname = "sft.install_backend"
    bl_label = "Install Backend"

    job_kind = "install"

    @classmethod
    def poll(cls, context):
        # the new environment replaces the installed one: not under a backend run that uses it
        return idle(cls, "install", "reconstruct", "plan", "solve", "import")

    def start(self, context) -> jobs.Job:
        if not bpy.app.online_access:
            err = AddonInputError(None, "Install Backend downloads the backend's libraries (about 340 MB) but Blender "
                                  "does not allow online access", "allow it in Preferences > System > Network > "
                                  "Allow Online Access, then press Install Backend again")
            _set_check_result(context, str(err))
            raise err
        venv = installed_venv()
        require(venv.parent.is_dir(), venv.parent, "the extension's user folder cannot be created",
                "check the permissions of Blender's user folder")
        _set_check_result(context, "")
        # Blender's own Python creates the environment: it matches the Python the wheels need
        return jobs.Job(sys.executable, [], None, kind=self.job_kind,
                        argv=interpreter.install_command(venv, sys.executable))

    def finish(self, context, job: jobs.Job):
        if job.state.status != "done":
            _set_check_result(context, f"Install {job.state.status}: {job.state.message}")
            return stopped(self, job, "Install Backend")
        check = interpreter.summarise_check(job.state.done.get("python", ""),
                                            [json.dumps(job.state.done.get("check", {}))], [])
        _set_check_result(context, check.summary)
        self.report({"INFO"}, f"backend installed in {job.state.done.get('seconds', 0):.0f} s: {check.summary}")
        return {"FINISHED"}


class SFT_OT_install_backend_cancel(CancelJob, bpy.types.Operator):
    """Stop the installation; the half-made environment is removed, the installed one kept"""

    bl_idname = "sft.install_backend_cancel"
    bl_label = "Cancel Install"
    job_kind = "install"


class CheckJob(jobs.Job):
    """``<python> -m backend check``: the report is the one JSON object it prints."""

    def __init__(self, python: str):
        self.python = python
        self.report: interpreter.CheckReport | None = None
        super().__init__(python, ["check"], None, kind="check")

    def on_finish(self, context):
        log = list(self.process.log)
        self.report = interpreter.summarise_check(self.python, log, log)


class SFT_OT_check_backend(JobModal, bpy.types.Operator):
    """Run '<python> -m backend check': the Mitsuba variant (CPU/LLVM or CUDA) or what is missing"""

    bl_idname = "sft.check_backend"
    bl_label = "Check Backend"

    job_kind = "check"

    def start(self, context) -> jobs.Job:
        python = backend_python(context)
        if not interpreter.exists(python):
            _set_check_result(context, f"{python}: interpreter not found. Fix: {interpreter.FIX_INSTALL}")
            raise AddonInputError(python, "interpreter not found", interpreter.FIX_INSTALL)
        _set_check_result(context, "Checking...")
        return CheckJob(python)

    def finish(self, context, job: jobs.Job):
        report = job.report or interpreter.CheckReport(False, job.state.message or "no answer")
        _set_check_result(context, report.summary)
        self.report({"INFO"} if report.ok else {"ERROR"}, report.summary)
        return {"FINISHED"} if report.ok else {"CANCELLED"}


CLASSES = (SFT_OT_install_backend, SFT_OT_install_backend_cancel, SFT_OT_check_backend)
