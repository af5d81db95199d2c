"""Add-on preferences: the interpreter that runs the backend, installing one, and a check."""

from pathlib import Path

import bpy
from bpy.props import StringProperty

from . import ROOT_PACKAGE, jobs
from .io import interpreter

VENV_FOLDER = "backend-python"


def installed_venv() -> Path:
    """Where Install Backend puts its environment: the extension's user folder (kept across
    updates of the extension), or a folder under the user scripts for a legacy add-on."""
    try:
        root = bpy.utils.extension_path_user(ROOT_PACKAGE, create=True)
    except (ValueError, RuntimeError):  # not loaded as an extension (a developer checkout)
        root = bpy.utils.user_resource("SCRIPTS", path="shape_from_tracing", create=True)
    return Path(root) / VENV_FOLDER


def backend_python(context=None) -> str:
    """The interpreter chosen in the preferences, else the automatic default."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ROOT_PACKAGE)
    chosen = addon.preferences.python.strip() if addon and addon.preferences else ""
    return bpy.path.abspath(chosen) if chosen else interpreter.default_python(installed=installed_venv())


def backend_ready(context=None) -> bool:
    """Whether some interpreter was chosen or set up (not whether it works: Check Backend tells)."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ROOT_PACKAGE)
    if addon and addon.preferences and addon.preferences.python.strip():
        return True
    return interpreter.has_interpreter(installed=installed_venv())


class SFT_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ROOT_PACKAGE

    python: StringProperty(
        name="Backend Python", subtype="FILE_PATH", default="",
        description="Python interpreter that runs the backend; it must import mitsuba. Empty: the one "
                    "Install Backend set up (or a developer checkout's .venv, $SFT_PYTHON, python3)")
    check_result: StringProperty(name="Check", default="", options={"SKIP_SAVE"})

    def draw(self, context):
        layout = self.layout
        box = layout.box().column()
        job = jobs.ACTIVE.get("install")
        if job is not None and job.running:
            box.progress(factor=job.state.fraction, type="BAR",
                         text=f"Installing: {job.state.stage or 'starting'} {job.state.fraction:.0%}")
            box.operator("sft.install_backend_cancel", icon="CANCEL")
        else:
            row = box.row()
            row.operator("sft.install_backend", icon="IMPORT")
            installed = interpreter.installed_python(installed_venv())
            box.label(text=f"Installed: {installed}" if installed else
                      "Downloads the backend's libraries (340 MB, 1.1 GB installed) into the extension's user folder",
                      icon="CHECKMARK" if installed else "INFO")
            if job is not None and job.state.status in ("failed", "cancelled"):
                box.label(text=job.state.headline(), icon="ERROR")
        layout.prop(self, "python")
        if not self.python.strip():
            layout.label(text=f"Automatic: {interpreter.default_python(installed=installed_venv())}", icon="INFO")
        check = jobs.ACTIVE.get("check")
        row = layout.row()
        row.enabled = not (check is not None and check.running)
        row.operator("sft.check_backend", icon="CHECKMARK", text="Checking..." if not row.enabled else "Check Backend")
        if self.check_result:
            ok = self.check_result.startswith("OK")
            layout.label(text=self.check_result, icon="CHECKMARK" if ok else "ERROR")


def register():
    bpy.utils.register_class(SFT_AddonPreferences)


def unregister():
    bpy.utils.unregister_class(SFT_AddonPreferences)
