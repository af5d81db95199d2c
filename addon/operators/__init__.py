"""Operators: each validates its input before touching the scene and reports one line on
bad input (``report({'ERROR'}, ...)``), leaving the scene unchanged."""

import bpy

from .. import jobs
from . import backend, cameras, capture, export, labels, modal, preset_plan, preview, reconstruct

CLASSES = (*backend.CLASSES, *capture.CLASSES, *cameras.CLASSES, *reconstruct.CLASSES,
           *preview.CLASSES, *labels.CLASSES, *export.CLASSES, *preset_plan.CLASSES, *modal.CLASSES)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    jobs.register()


def unregister():
    jobs.unregister()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
