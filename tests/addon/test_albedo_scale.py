"""The add-on side of the albedo's scale: with an imported map (Captured HDR) the panel offers
"Strength calibrated", which puts ``--map-calibrated`` on the backend's command line; with a
fitted light neither the setting nor the flag appears."""

from __future__ import annotations

from importlib import import_module

from .test_panels import draw


def test_a_calibrated_map_strength_goes_to_the_backend(context, extension, tmp_path):
    reconstruct = import_module(f"{extension.__name__}.addon.operators.reconstruct")
    sft = context.scene.sft
    assert not sft.map_calibrated
    sft.lighting = "CAPTURED"
    sft.env_path = str(tmp_path / "sky.exr")
    assert ("prop", "map_calibrated") in draw("SFT_PT_reconstruct", context)
    assert "--map-calibrated" not in reconstruct.method_args(sft)
    sft.map_calibrated = True
    argv = reconstruct.method_args(sft)
    assert "--map-calibrated" in argv and argv[argv.index("--env") + 1].endswith("sky.exr")
    sft.lighting = "ESTIMATE"  # a fitted map: its scale is the mean-albedo convention's
    assert "--map-calibrated" not in reconstruct.method_args(sft)
    assert ("prop", "map_calibrated") not in draw("SFT_PT_reconstruct", context)
