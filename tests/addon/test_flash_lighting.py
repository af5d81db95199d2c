"""The add-on side of ``--lighting flash``: the Lighting setting's "Camera flash" becomes
``--lighting flash`` on the backend's command line (an imported map does not go along), and
the Reconstruct panel says what it fits."""

from __future__ import annotations

import json
import types
from importlib import import_module

import bpy
import numpy as np

from backend.capture.images import write_image

from .test_panels import RecordingLayout


def _lighting_args_and_labels(reconstruct, sft, context, lighting: str) -> tuple[list[str], list[str]]:
    """Reconstruct's method arguments and the Reconstruct panel's labels with Lighting on ``lighting``."""
    sft.lighting = lighting
    log = []
    bpy.types.SFT_PT_reconstruct.draw(types.SimpleNamespace(layout=RecordingLayout(log)), context)
    return reconstruct.method_args(sft), [entry[1] for entry in log if entry[0] == "label"]


def test_camera_flash_puts_lighting_flash_on_the_command_line(context, extension, tmp_path):
    reconstruct = import_module(f"{extension.__name__}.addon.operators.reconstruct")
    sft = context.scene.sft
    items = {item.identifier: item.name for item in sft.bl_rna.properties["lighting"].enum_items}
    assert items["FLASH"] == "Camera flash"
    sft.lighting = "FLASH"
    sft.env_path = str(tmp_path / "sky.exr")  # a map imported earlier: the flash replaces it
    argv = reconstruct.reconstruct_args(tmp_path / "capture", tmp_path / "run", None, "",
                                        reconstruct.method_args(sft))
    assert argv[argv.index("--lighting") + 1] == "flash" and "--env" not in argv
    log = []
    bpy.types.SFT_PT_reconstruct.draw(types.SimpleNamespace(layout=RecordingLayout(log)), context)
    labels = [entry[1] for entry in log if entry[0] == "label"]
    assert any(label.startswith("A flash at each camera, intensity fitted") for label in labels)
    sft.lighting = "CAPTURED"  # the other choices are unchanged
    argv = reconstruct.method_args(sft)
    assert "--lighting" not in argv and argv[argv.index("--env") + 1].endswith("sky.exr")


def test_lighting_on_the_camera_puts_lighting_rig_on_the_command_line_and_leaves_the_world(context, extension,
                                                                                          tmp_path):
    """"Estimate, on the camera" becomes ``--lighting rig``; its map, fixed to the camera, is not
    put in the World after the run (a World cannot turn with the view)."""
    reconstruct = import_module(f"{extension.__name__}.addon.operators.reconstruct")
    sft = context.scene.sft
    items = {item.identifier: item.name for item in sft.bl_rna.properties["lighting"].enum_items}
    assert items["RIG"] == "Estimate, on the camera"
    argv, labels = _lighting_args_and_labels(reconstruct, sft, context, "RIG")
    assert argv[argv.index("--lighting") + 1] == "rig" and "--env" not in argv
    assert any(label.startswith("A map fixed to the camera") for label in labels)
    run = tmp_path / "run"
    run.mkdir()
    (run / "environment.exr").write_bytes(b"not read")
    world = context.scene.world
    note = reconstruct._load_estimated_lighting(context, run)
    assert "camera rig" in note and context.scene.world is world
    sft.lighting = "ESTIMATE"


def test_auto_is_the_default_and_world_plus_camera_puts_lighting_world_rig_on_the_command_line(context, extension,
                                                                                                tmp_path):
    """With no map and no lights imported the Lighting menu is on Auto (``--lighting auto``);
    "Estimate, world + camera" becomes ``--lighting world+rig``, and after its run the World
    shows the world-fixed map (RUN/environment.exr), the camera-fixed one left in the run folder."""
    reconstruct = import_module(f"{extension.__name__}.addon.operators.reconstruct")
    sft = context.scene.sft
    items = {item.identifier: item.name for item in sft.bl_rna.properties["lighting"].enum_items}
    assert items["AUTO"] == "Auto" and items["WORLD_RIG"] == "Estimate, world + camera"
    assert sft.bl_rna.properties["lighting"].default == "AUTO" and sft.lighting == "AUTO"
    argv, labels = _lighting_args_and_labels(reconstruct, sft, context, "AUTO")
    assert argv[argv.index("--lighting") + 1] == "auto" and "--env" not in argv
    assert any(label.startswith("Chosen by a short probe") for label in labels)
    argv, labels = _lighting_args_and_labels(reconstruct, sft, context, "WORLD_RIG")
    assert argv[argv.index("--lighting") + 1] == "world+rig" and "--env" not in argv
    assert any(label.startswith("A world-fixed map plus a camera-fixed one") for label in labels)
    run = tmp_path / "run"
    run.mkdir()
    write_image(run / "environment.exr", np.full((8, 16, 3), 0.5, np.float32))
    (run / "report.json").write_text(json.dumps({"lighting": {"model": "environment map (estimated)",
                                                              "frame": "world+camera", "file": "environment.exr",
                                                              "rig_file": "environment_rig.exr"}}))
    note = reconstruct._load_estimated_lighting(context, run)
    assert "environment_rig.exr" in note and "World lit" in note
    nodes = [n.bl_idname for n in context.scene.world.node_tree.nodes]
    assert "ShaderNodeTexEnvironment" in nodes
    sft.lighting = "AUTO"
