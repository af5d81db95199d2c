"""The results row "Exposure ±0.30 stops": what a run's per-frame gains refined (report.json
``exposure``, backend.lighting.exposure), in words; bpy-free, read by capture_state once per
refresh and never while drawing.

A frame's exposure is its mean log2-gain over the three channels, its white balance what is
left per channel; the row gives half the range of each over the fitted frames (stops), so
"±0.30 stops" is a swing of 0.6 stops from the darkest frame to the brightest."""

from __future__ import annotations

import json
import math
from pathlib import Path

REPORT = "report.json"


def spread(gains: dict) -> tuple[float, float] | None:
    """(exposure, white balance) half-ranges in stops of ``{frame: [r, g, b]}``; None when
    there is no valid gain."""
    rows = [[math.log2(float(x)) for x in g] for g in gains.values()
            if isinstance(g, (list, tuple)) and len(g) == 3 and all(float(x) > 0 for x in g)]
    if not rows:
        return None
    exposure = [sum(r) / 3 for r in rows]
    balance = [[x - e for x in r] for r, e in zip(rows, exposure)]
    wb = max((max(b[c] for b in balance) - min(b[c] for b in balance)) / 2 for c in range(3))
    return (max(exposure) - min(exposure)) / 2, wb


def line(report: dict) -> str:
    """The row's text for a finished run's report; "" when the run fitted no per-frame gains."""
    exposure = report.get("exposure") if isinstance(report, dict) else None
    if not isinstance(exposure, dict) or exposure.get("model") != "per-frame":
        return ""
    try:
        found = spread(exposure.get("gains") or {})
    except (TypeError, ValueError):
        return ""
    if found is None:
        return ""
    return f"Exposure ±{found[0]:.2f} stops, white balance ±{found[1]:.2f} ({len(exposure['gains'])} frames)"


def read(run: Path) -> str:
    """:func:`line` of ``run``/report.json ("" when it is missing or unreadable)."""
    try:
        return line(json.loads((Path(run) / REPORT).read_text()))
    except (OSError, ValueError):
        return ""
