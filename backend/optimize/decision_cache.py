"""A run's first effects decision, kept beside the capture (``capture.probe_cache``, the cache
``effects``) so that a later run on the same capture, initial mesh and settings makes the
same decision without its probes: the bounce, self-shadowing and highlight renders and the
cost probe's geometry steps (:mod:`backend.render.effects`, :mod:`.effect_costs`)."""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..capture import probe_cache
from ..render import effects
from .effect_costs import EffectCost

NAME = "effects"
# what the decision depends on besides its inputs: the renders, the costs, how the run calls them
CODE = (Path(effects.__file__).parent, Path(__file__).with_name("effect_costs.py"),
        Path(__file__).with_name("appearance.py"), Path(__file__).with_name("objective.py"),
        Path(__file__).with_name("views.py"), Path(__file__).parents[1] / "material")
# settings that do not reach the first decision
IGNORED = ("time_budget_s", "track_metrics")


def key(capture, config, mesh, material, views, reason: str) -> str:
    """The decision's key: the capture's content, the run's settings (less ``IGNORED``), the
    mesh it is measured on, the material's kind, the probe views' count and size, the code
    (``CODE``), Mitsuba and the machine (the cost probe times steps)."""
    settings = {k: v for k, v in dataclasses.asdict(config).items() if k not in IGNORED}
    shape = np.asarray(views[0].target).shape if views else None
    mesh_hash = hashlib.sha256(np.ascontiguousarray(mesh.vertices, np.float64).tobytes()
                               + np.ascontiguousarray(mesh.faces, np.int64).tobytes()).hexdigest()
    return probe_cache.key(capture, settings=settings, mesh=mesh_hash, material=getattr(material, "KIND", None),
                           views=len(views), shape=shape, reason=reason, code=probe_cache.code_version(*CODE),
                           mitsuba=mi.__version__, variant=mi.variant(), machine=probe_cache.machine())


def load(capture, entry_key: str) -> tuple[effects.EffectsDecision, dict | None] | None:
    """(the decision, the cost probe's {effect: EffectCost} or None) stored under ``entry_key``,
    its ``measured`` marked ``cache: "hit"``; None on a miss."""
    entry = probe_cache.load(capture, NAME, entry_key)
    try:
        decision = effects.EffectsDecision(**entry["decision"])
        costs = None if entry.get("costs") is None else {n: EffectCost(**c) for n, c in entry["costs"].items()}
    except (TypeError, KeyError, ValueError):
        return None
    decision.measured = {**decision.measured, "cache": "hit"}
    return decision, costs


def store(capture, entry_key: str, decision: effects.EffectsDecision, costs: dict | None) -> None:
    """Keep ``decision`` (as ``effects.decide`` returned it) and the cost probe's ``costs``."""
    probe_cache.store(capture, NAME, entry_key, {
        "decision": decision.to_json(),
        "costs": None if costs is None else {n: dataclasses.asdict(c) for n, c in costs.items()}})
