"""Quality presets (Draft / Balanced / Final) and their calibrated cost.

A preset is a set of overrides of ``ReconstructConfig``'s defaults; options given on the
command line win over it. ``backend/presets.json`` (written by ``python -m backend bench
calibrate``) records, per preset, the wall clock and F1@0.01 it reached on the dragon
benchmark on the machine named there; :func:`preset_for_budget` reads it to turn a time
budget into a preset."""

from __future__ import annotations

import json
from pathlib import Path

PRESETS = {
    "draft": {"max_size": 96, "coarse_size": 48, "initial_faces": 2000, "max_levels": 3, "level_iterations": 120,
              "validation_views": 4},
    "balanced": {},
    # Balanced's start with more and longer levels: on the dragon more levels bought more F1 per
    # second than more views per step or a finer start (bench/report.md)
    "final": {"max_size": 256, "max_levels": 16, "level_iterations": 600, "level_tolerance": 0.001},
}
DEFAULT = "balanced"
CALIBRATION_FILE = Path(__file__).resolve().parents[1] / "presets.json"


def load_calibration(path: Path = CALIBRATION_FILE) -> dict:
    """The calibration file, or {} when it is absent or unreadable."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) and isinstance(doc.get("presets"), dict) else {}


def calibrated(path: Path = CALIBRATION_FILE) -> dict[str, dict]:
    """Calibration entries that give an expected time, by preset name."""
    return {name: p for name, p in load_calibration(path).get("presets", {}).items()
            if name in PRESETS and isinstance(p, dict) and isinstance(p.get("expected_minutes"), (int, float))}


def preset_for_budget(minutes: float, path: Path = CALIBRATION_FILE, default: str = DEFAULT) -> str:
    """The most accurate calibrated preset whose expected time fits ``minutes``.

    When none fits, the fastest calibrated preset (it will run against the budget); without a
    calibration file (or with no usable entries), ``default``."""
    entries = calibrated(path)
    if not entries:
        return default
    fits = [n for n, p in entries.items() if p["expected_minutes"] <= minutes]
    if fits:
        return max(fits, key=lambda n: (entries[n].get("expected_f1") or 0.0, -entries[n]["expected_minutes"]))
    return min(entries, key=lambda n: entries[n]["expected_minutes"])
