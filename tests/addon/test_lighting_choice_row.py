"""The panel's row for ``--lighting auto`` (bpy-free: addon.io.progress folds the events)."""

from __future__ import annotations

from addon.io.progress import RunState, lighting_choice_summary


def test_the_winner_and_its_margin_become_one_line():
    state = RunState()
    state.update({"event": "lighting_choice", "winner": "rig", "runner_up": "estimate", "margin_db": 1.234,
                  "candidates": []})
    assert state.lighting_choice == "lighting: rig map, by 1.2 dB"
    assert lighting_choice_summary({"winner": "estimate", "margin_db": None}) == "lighting: world map (not probed)"
    assert lighting_choice_summary({"winner": "world+rig", "margin_db": 2.0, "runoff": [{}, {}]}) == \
        "lighting: world + rig maps, by 2.0 dB (run-off)"
    assert lighting_choice_summary({"winner": "world+rig", "runner_up": "estimate", "margin_db": -0.225,
                                    "kept": True}) == "lighting: world + rig maps kept, 0.2 dB behind the world map"
    state.update({"event": "lighting", "model": "estimate", "frame": "camera", "resolution": [16, 8],
                  "when": "fitted", "stage": "constant"})
    assert state.lighting_choice == "lighting: rig map, by 1.2 dB"  # a later lighting event leaves the row
