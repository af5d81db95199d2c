"""Check that the chosen interpreter can run the backend."""

import bpy

from .. import ROOT_PACKAGE, interpreter
from ..preferences import backend_python


class SFT_OT_check_backend(bpy.types.Operator):
    """Run '<python> -m backend check' and report what the interpreter is missing"""

    bl_idname = "sft.check_backend"
    bl_label = "Check Backend"

    def execute(self, context):
        report = interpreter.check(backend_python(context))
        addon = context.preferences.addons.get(ROOT_PACKAGE)
        if addon and addon.preferences:
            addon.preferences.check_result = report.summary
        self.report({"INFO"} if report.ok else {"ERROR"}, report.summary)
        return {"FINISHED"} if report.ok else {"CANCELLED"}


CLASSES = (SFT_OT_check_backend,)
