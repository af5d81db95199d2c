"""The "Shape from Tracing" sidebar tab of the 3D viewport."""

import bpy

from .. import accuracy_curve
from . import panels


def register():
    accuracy_curve.register()
    for cls in panels.CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(panels.CLASSES):
        bpy.utils.unregister_class(cls)
    accuracy_curve.unregister()
