"""The Reconstruct panel's exposure row: the finished run's per-frame gains in stops, from the
cached report (capture_state), not read while drawing."""

from __future__ import annotations

import json

from .test_panels import draw


def test_a_finished_run_with_gains_shows_their_spread(context, addon, tmp_path):
    gains = {"0000": [2 ** 0.3, 2 ** 0.3, 2 ** 0.3], "0001": [2 ** -0.3, 2 ** -0.3, 2 ** -0.3]}
    (tmp_path / "report.json").write_text(json.dumps({"exposure": {"model": "per-frame", "gains": gains}}))
    context.scene.sft.run_dir = str(tmp_path)  # its update callback reads the folder
    try:
        row = "Exposure ±0.30 stops, white balance ±0.00 (2 frames)"
        assert ("label", row) in draw("SFT_PT_reconstruct", context)
        (tmp_path / "report.json").write_text(json.dumps({"exposure": {"model": "off", "mode": "auto"}}))
        assert ("label", row) in draw("SFT_PT_reconstruct", context), "drawing reads the cache, not the file"
        addon.capture_state.refresh(context.scene)
        assert not any(e[0] == "label" and e[1].startswith("Exposure") for e in draw("SFT_PT_reconstruct", context))
    finally:
        context.scene.sft.run_dir = ""
