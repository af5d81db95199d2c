"""Helpers shared by the operators."""

from pathlib import Path

import bpy

from ..errors import require


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


def fail(operator, err) -> set[str]:
    operator.report({"ERROR"}, str(err))
    return {"CANCELLED"}
