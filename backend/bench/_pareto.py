"""Pareto fronts of accuracy against time, and what each knob buys per second.

A run is *dominated* when another run took no more time and scored at least as well,
being strictly better in one of the two. The front is what remains, ordered by time:
each point on it is the most accurate result any run reached within that time."""

from __future__ import annotations

import math
from typing import Sequence


def front(times: Sequence[float], scores: Sequence[float]) -> list[int]:
    """Indices of the non-dominated points (less time and more score are better), by time.

    Points with a non-finite time or score are left out; of identical points the first is kept."""
    ok = [i for i in range(len(times)) if math.isfinite(times[i]) and math.isfinite(scores[i])]
    best, out = -math.inf, []
    for i in sorted(ok, key=lambda i: (times[i], -scores[i], i)):
        if scores[i] > best:
            out.append(i)
            best = scores[i]
    return out


def changed(a: dict, b: dict) -> dict:
    """The knobs whose values differ: ``{knob: (a's value, b's value)}``."""
    return {k: (a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)}


def rate(d_score: float, d_seconds: float) -> float:
    """Score gained per second spent (for a cheaper, worse change: score lost per second
    saved); +inf for a gain that costs no time or saves time, -inf for a loss that costs
    none, nan for no change at all."""
    if d_score > 0 and d_seconds <= 0:
        return math.inf
    if d_seconds == 0:
        return math.nan if d_score == 0 else -math.inf
    return d_score / d_seconds


def knob_effects(rows: Sequence[dict], base: str, time_key: str = "seconds", score_key: str = "f1") -> list[dict]:
    """One-knob-at-a-time effects around the run named ``base``.

    ``rows`` are dicts with ``name``, ``knobs`` (dict), ``time_key`` and ``score_key``. For
    every run that differs from the base in exactly one knob: the knob, its two values, the
    time and score differences and their ratio, best ratio first."""
    ref = next((r for r in rows if r["name"] == base), None)
    if ref is None:
        return []
    out = []
    for r in rows:
        diff = changed(ref["knobs"], r["knobs"])
        if len(diff) != 1:
            continue
        (knob, (was, now)), = diff.items()
        ds, dq = r[time_key] - ref[time_key], r[score_key] - ref[score_key]
        out.append({"name": r["name"], "knob": knob, "from": was, "to": now, "d_seconds": ds, "d_score": dq,
                    "per_second": rate(dq, ds)})
    return sorted(out, key=lambda e: (-e["per_second"] if not math.isnan(e["per_second"]) else math.inf))


def front_steps(rows: Sequence[dict], time_key: str = "seconds", score_key: str = "f1") -> list[dict]:
    """Walk along the front: from each point to the next, the extra time, the extra score,
    the score bought per second and the knobs that changed (what to buy at that budget)."""
    idx = front([r[time_key] for r in rows], [r[score_key] for r in rows])
    steps = []
    for a, b in zip(idx, idx[1:]):
        ra, rb = rows[a], rows[b]
        ds, dq = rb[time_key] - ra[time_key], rb[score_key] - ra[score_key]
        steps.append({"from": ra["name"], "to": rb["name"], "budget_s": ra[time_key], "d_seconds": ds,
                      "d_score": dq, "per_second": rate(dq, ds), "knobs": changed(ra["knobs"], rb["knobs"])})
    return steps
