"""Add-on preferences: the interpreter that runs the backend, and a check of it."""

import bpy
from bpy.props import StringProperty

from . import ROOT_PACKAGE, interpreter


def backend_python(context=None) -> str:
    """The interpreter chosen in the preferences, else the automatic default."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ROOT_PACKAGE)
    chosen = addon.preferences.python.strip() if addon and addon.preferences else ""
    return bpy.path.abspath(chosen) if chosen else interpreter.default_python()


class SFT_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ROOT_PACKAGE

    python: StringProperty(
        name="Backend Python", subtype="FILE_PATH", default="",
        description="Python interpreter that runs the backend; it must import mitsuba "
                    "(pip install -r requirements.txt). Empty: the add-on's .venv, else "
                    "$SFT_PYTHON, else python3")
    check_result: StringProperty(name="Check", default="", options={"SKIP_SAVE"})

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "python")
        if not self.python.strip():
            layout.label(text=f"Automatic: {interpreter.default_python()}", icon="INFO")
        row = layout.row()
        row.operator("sft.check_backend", icon="CHECKMARK")
        if self.check_result:
            ok = self.check_result.startswith("OK")
            layout.label(text=self.check_result, icon="CHECKMARK" if ok else "ERROR")


def register():
    bpy.utils.register_class(SFT_AddonPreferences)


def unregister():
    bpy.utils.unregister_class(SFT_AddonPreferences)
