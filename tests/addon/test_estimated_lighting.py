"""The add-on side of ``--lighting estimate``: the run's RUN/environment.exr lights the World
(Blender's equirectangular convention, rotation 0, strength 1)."""

from __future__ import annotations

import importlib

import numpy as np

from backend.capture.images import write_image


def test_estimated_environment_lights_the_world(context, extension, tmp_path):
    world = importlib.import_module(f"{extension.__name__}.addon.world")
    assert world.load_estimated_environment(context.scene, tmp_path) is False  # no map: the World is left alone
    pixels = np.full((16, 32, 3), 0.25, np.float32)
    pixels[:8] = 2.0  # bright sky
    write_image(tmp_path / "environment.exr", pixels)
    assert world.load_estimated_environment(context.scene, tmp_path) is True
    nodes = context.scene.world.node_tree.nodes
    env = next(n for n in nodes if n.type == "TEX_ENVIRONMENT")
    assert env.image.size[:] == (32, 16) and env.projection == "EQUIRECTANGULAR"
    background = next(n for n in nodes if n.type == "BACKGROUND")
    assert background.inputs["Strength"].default_value == 1.0
    mapping = next(n for n in nodes if n.type == "MAPPING")
    assert tuple(mapping.inputs["Rotation"].default_value) == (0.0, 0.0, 0.0)
    # a second run into the same folder: its own map is shown, not the cached image
    write_image(tmp_path / "environment.exr", np.full((16, 32, 3), 3.0, np.float32))
    assert world.load_estimated_environment(context.scene, tmp_path)
    env = next(n for n in context.scene.world.node_tree.nodes if n.type == "TEX_ENVIRONMENT")
    assert abs(env.image.pixels[0] - 3.0) < 1e-3
