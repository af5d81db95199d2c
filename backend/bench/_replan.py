"""``bench plan --replan``: the time and held-out PSNR a finished ``bench plan`` run would have
been promised by the current cost model (optimize/plan.py) and gains (optimize/forecast.py),
from the step costs and the probe it recorded.

A run's plan is a function of its measured step costs (the ``preset`` event's ``plan.costs``),
its settings, its capture's views and the calibration's levels, so a change to the model
(the finishing stages' counts, what a step costs) can be checked on runs already made,
without timing them again. The probe's seconds are added as a run adds them. Likewise the
predicted PSNR is the recorded probe plus the current gain."""

from __future__ import annotations

import json
from pathlib import Path

from .sweep import load_history


def replan(run: Path, capture: Path) -> float:
    """Predicted minutes of the run in ``run`` (its events and report) on ``capture``; the
    Mitsuba variant must be chosen (``replan_rows`` does)."""
    from ..capture.load import load_capture
    from ..optimize import plan
    from ..optimize.config import ReconstructConfig
    from ..optimize.presets import calibrated
    from ..optimize.views import ViewSet

    preset = next(e for e in load_history(run / "events.jsonl") if e["event"] == "preset")
    config = ReconstructConfig(**json.loads((run / "report.json").read_text())["settings"])
    viewset = ViewSet(load_capture(capture), config.max_size)
    costs = plan.StepCosts([plan.Point(**p) for p in preset["plan"]["costs"]["points"]])
    entry = calibrated(kind=preset["lighting_kind"]).get(preset["preset"])
    predicted = plan.predict(preset["preset"], config, costs, plan.pixels_for(viewset), len(viewset),
                             config.material == "staged", entry)
    predicted.fixed_s += (preset.get("probe") or {}).get("seconds", 0.0)
    return round(predicted.minutes, 2)


def replan_rows(out: Path, rows: list[dict]) -> list[dict]:
    """``rows`` (plan.json's) with ``predicted_minutes``, ``time_error``, ``predicted_psnr`` and
    ``psnr_error`` from the current model and gains; the recorded promises kept as
    ``recorded_minutes`` and ``recorded_psnr``."""
    from .. import variant
    from ..optimize.forecast import predicted_psnr

    variant.choose()
    fresh = []
    for row in rows:
        row = dict(row)
        if row.get("rc") == 0 and row.get("predicted_minutes") is not None:
            minutes = replan(out / "runs" / row["capture"], out / "captures" / row["capture"])
            row.update(recorded_minutes=row["predicted_minutes"], predicted_minutes=minutes,
                       time_error=round(minutes * 60 / row["seconds"] - 1, 3))
        if row.get("probe_psnr") is not None:
            psnr = predicted_psnr({"psnr": row["probe_psnr"], "lighting_kind": row.get("lighting_kind")}, row["preset"])
            row.update(recorded_psnr=row.get("predicted_psnr"), predicted_psnr=psnr)
            if psnr is not None and row.get("psnr") is not None:
                row["psnr_error"] = round(psnr - row["psnr"], 2)
        fresh.append(row)
    return fresh
