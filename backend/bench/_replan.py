"""``bench plan --replan``: the time and held-out PSNR a finished ``bench plan`` run would have
been promised by the current cost model (planning/time_plan.py) and gains (planning/accuracy_forecast.py),
from the step costs and the probe it recorded.

A run's plan is a function of its measured step costs (the ``preset`` event's ``plan.costs``),
its settings, its capture's views and the calibration's levels, so a change to the model
(the finishing stages' counts, what a step costs) can be checked on runs already made,
without timing them again. The probe's seconds are added as a run adds them. Likewise the
predicted PSNR is the recorded probe plus the current gain, and the time left during the run
(planning/remaining.py) is its events replayed through the current code."""

from __future__ import annotations

import json
from pathlib import Path

from .. import variant
from ..capture.load import load_capture
from ..optimize.config import ReconstructConfig
from ..optimize.views import ViewSet
from ..planning import time_plan as plan
from ..planning.accuracy_forecast import predicted_psnr
from ..planning.presets import calibrated
from ..planning.remaining import Remaining
from .sweep import load_history


CHECKPOINTS = (0.25, 0.5, 0.75)  # shares of a run's time after its plan, where the time left is judged


def replan(run: Path, capture: Path) -> tuple[float, dict, dict]:
    """Predicted minutes of the run in ``run`` (its events and report) on ``capture``, and the
    errors of its time left at the CHECKPOINTS, replayed (``live_errors``) and as its progress
    events recorded them; the Mitsuba variant must be chosen (``replan_rows`` does)."""
    events = load_history(run / "events.jsonl")
    preset = planned(events)
    config = ReconstructConfig(**json.loads((run / "report.json").read_text())["settings"])
    viewset = ViewSet(load_capture(capture), config.max_size)
    costs = plan.StepCosts([plan.Point(**p) for p in preset["plan"]["costs"]["points"]])
    entry = calibrated(kind=preset["lighting_kind"]).get(preset["preset"])
    predicted = plan.predict(preset["preset"], config, costs, plan.pixels_for(viewset), len(viewset),
                             config.material == "staged", entry)
    predicted.fixed_s += (preset.get("probe") or {}).get("seconds", 0.0)
    return round(predicted.minutes, 2), live_errors(events, predicted, config.time_budget_s), said_errors(events)


def planned(events: list[dict]) -> dict:
    """The run's ``preset`` event that carries its plan (a run announces the preset at once, and
    again with the plan once its first level has ended)."""
    return next(e for e in reversed(events) if e["event"] == "preset" and e.get("plan"))


def checkpoints(events: list[dict]) -> tuple[float, float, list[tuple[str, float]]]:
    """The times of the run's ``preset`` event and of its last event, and for each of the
    CHECKPOINTS (a share of the time between them) the share as a key and its time."""
    start = planned(events)["time"]
    end = events[-1]["time"]
    return start, end, [(str(share), start + share * (end - start)) for share in CHECKPOINTS]


def live_errors(events: list[dict], predicted, budget_s: float | None = None) -> dict:
    """At each of the CHECKPOINTS: the end the time left points to, over the real end, less 1,
    replayed through planning/remaining.py with the phases of ``predicted`` (a PresetPlan)."""
    start, end, points = checkpoints(events)
    out = {}
    for key, at in points:
        remaining = Remaining.from_plan(predicted, budget_s)
        for e in events:
            if e["time"] > at:
                break
            if e["time"] >= start:
                remaining.observe(e["event"], e, e["time"])
        left = remaining.seconds(at)
        out[key] = None if left is None else round((at + left) / end - 1, 3)
    return out


def said_errors(events: list[dict]) -> dict:
    """The same errors as the run's own progress events said them: their last ``eta_s`` before
    each checkpoint."""
    _, end, points = checkpoints(events)
    out = {}
    for key, at in points:
        said = [e["time"] + e["eta_s"] for e in events
                if e["time"] <= at and e["event"] == "progress" and e.get("eta_s") is not None]
        out[key] = round(said[-1] / end - 1, 3) if said else None
    return out


def replan_rows(out: Path, rows: list[dict]) -> list[dict]:
    """``rows`` (plan.json's) with ``predicted_minutes``, ``time_error``, ``live_error`` (the time
    left at the CHECKPOINTS), ``predicted_psnr`` and ``psnr_error`` from the current model and
    gains; the recorded promises kept as ``recorded_minutes``, ``recorded_eta_error`` and
    ``recorded_psnr``."""
    variant.choose()
    fresh = []
    for row in rows:
        row = dict(row)
        if row.get("rc") == 0 and row.get("predicted_minutes") is not None:
            minutes, live, said = replan(out / "runs" / row["capture"], out / "captures" / row["capture"])
            row.update(recorded_minutes=row["predicted_minutes"], predicted_minutes=minutes,
                       time_error=round(minutes * 60 / row["seconds"] - 1, 3), live_error=live,
                       recorded_eta_error=said)
        if row.get("probe_psnr") is not None:
            psnr = predicted_psnr({"psnr": row["probe_psnr"], "lighting_kind": row.get("lighting_kind")}, row["preset"])
            row.update(recorded_psnr=row.get("predicted_psnr"), predicted_psnr=psnr)
            if psnr is not None and row.get("psnr") is not None:
                row["psnr_error"] = round(psnr - row["psnr"], 2)
        fresh.append(row)
    return fresh
