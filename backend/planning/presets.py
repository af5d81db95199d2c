"""Quality presets (Draft / Balanced / Final): overrides of ``ReconstructConfig``'s defaults,
and their calibrated cost per kind of lighting (``backend/presets.json``, ``preset_for_budget``)."""

from __future__ import annotations

import json
from pathlib import Path

PRESETS = {
    # a quick look: no polish rounds and two material cycles on the converged surface (with the
    # staged material the polish and the long final cycles took two thirds of Draft's time for
    # a few F1 points; docs/notes/2026-12-02-draft-preset.md)
    "draft": {"max_size": 96, "coarse_size": 48, "initial_faces": 2000, "max_levels": 3, "level_iterations": 120,
              "validation_views": 4, "polish_rounds": 0, "final_material_cycles": 2},
    # at most six levels; Final runs at least one more, then until the surface stops improving,
    # so that it never stops short of Balanced (a flat level can end refinement early)
    "balanced": {"max_levels": 6},
    "final": {"min_levels": 7},
}
DEFAULT = "balanced"
# a time budget at least this many times the best fitting preset's time runs the next one, cut
# at the budget: Draft stops when its levels end, however much of the budget is left
# (docs/notes/2026-12-02-budget-fill.md)
FILL_FACTOR = 2.0
CALIBRATION_FILE = Path(__file__).resolve().parents[1] / "presets.json"


def load_calibration(path: Path = CALIBRATION_FILE) -> dict:
    """The calibration file, or {} when it is absent or unreadable."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) and isinstance(doc.get("presets"), dict) else {}


def lighting_kind(capture, lighting: str = "captured") -> str:
    """The kind of calibration scene a capture compares with: 'environment' when an
    environment map lights it (captured, or ``lighting`` 'estimate': one is fitted; 'auto' before
    its probe has chosen), else
    'point' (point lights or a flash)."""
    if lighting in ("estimate", "rig", "world+rig", "auto") or (capture is not None and capture.environment is not None):
        return "environment"
    return "point"


def _kind(kind: str, path: Path) -> dict:
    """The calibration of ``kind`` ({"scene", "presets", ...}): its entry under ``kinds``; for
    'point' the top level of a file without kinds; {} when not calibrated."""
    doc = load_calibration(path)
    sub = (doc.get("kinds") or {}).get(kind)
    return sub if isinstance(sub, dict) else doc if kind == "point" else {}


def calibration_scene(kind: str = "point", path: Path = CALIBRATION_FILE) -> str | None:
    """The description of the scene that calibrated ``kind`` (None: not calibrated)."""
    return _kind(kind, path).get("scene")


def calibrated(path: Path = CALIBRATION_FILE, kind: str = "point") -> dict[str, dict]:
    """Calibration entries that give an expected time, by preset name, from the calibration
    scene of ``kind`` (the top level, the dragon's, for 'point'; {} for a kind not calibrated)."""
    presets = _kind(kind, path).get("presets") or {}
    return {name: p for name, p in presets.items()
            if name in PRESETS and isinstance(p, dict) and isinstance(p.get("expected_minutes"), (int, float))}


def preset_for_budget(minutes: float, path: Path = CALIBRATION_FILE, default: str = DEFAULT,
                      kind: str = "point") -> str:
    """The most accurate calibrated preset whose expected time fits ``minutes``, by the
    calibration of ``kind`` (the capture's lighting; the point-lit one where that kind is
    not calibrated), or the next costlier one, cut by the budget, when ``minutes`` is at
    least ``FILL_FACTOR`` times that preset's time. A preset marked ``dominated_by`` is
    passed by.

    When none fits, the fastest calibrated preset (it will run against the budget); without a
    calibration file (or with no usable entries), ``default``.

    A preset is a set of overrides of ``ReconstructConfig``'s defaults; options given on the
    command line win over it. ``backend/presets.json`` (written by ``python -m backend bench
    calibrate``) records, per preset, the wall clock and F1@0.01 it reached on the dragon
    benchmark on the machine named there (and, under ``kinds``, on the calibration scene of each
    kind of lighting); :func:`preset_for_budget` reads the capture's kind (the dragon's where
    that kind is not calibrated) to turn a time budget into a preset.
    """
    entries = calibrated(path, kind) or calibrated(path)
    if not entries:
        return default
    # a preset a cheaper one dominates on the kind's scene buys nothing there
    entries = {n: p for n, p in entries.items() if not p.get("dominated_by")} or entries
    fits = [n for n, p in entries.items() if p["expected_minutes"] <= minutes]
    if not fits:
        return min(entries, key=lambda n: entries[n]["expected_minutes"])
    best = max(fits, key=lambda n: (entries[n].get("expected_f1") or 0.0, -entries[n]["expected_minutes"]))
    # a budget the best fit would mostly leave unused is better spent on the next preset, cut
    # at the budget (measured on both calibration scenes: docs/results.md, "Presets calibrated")
    costlier = [n for n, p in entries.items() if p["expected_minutes"] > entries[best]["expected_minutes"]]
    if costlier and minutes >= FILL_FACTOR * entries[best]["expected_minutes"]:
        return min(costlier, key=lambda n: entries[n]["expected_minutes"])
    return best
