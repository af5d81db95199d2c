"""The backend's quality presets, read from its preset file (bpy-free).

``backend/presets.json`` (written by ``python -m backend bench calibrate``, shipped in the
extension with ``backend/``) names the presets and holds each one's calibrated cost:
``{"machine": ..., "presets": {"draft": {"expected_minutes": ..., "expected_f1": ...}, ...},
"kinds": {"point" | "environment": {"presets": {...}}}}``. It is read as JSON: the backend's
Python imports Mitsuba and never loads in Blender. Without the file the Quality list holds
``FALLBACK_NAMES`` and the panel says "not calibrated"."""

from __future__ import annotations

import json
from pathlib import Path

from . import interpreter

FALLBACK_NAMES = ("draft", "balanced", "final")  # the backend's presets, for a missing file
DESCRIPTIONS = {  # tooltips by preset name; a name without one gets a generic line
    "draft": "Coarse mesh and few iterations: a quick look",
    "balanced": "Six refinement levels: the default trade-off between time and accuracy",
    "final": "At least seven refinement levels, then until the surface stops improving: the slowest; "
             "the most accurate where the views show finer detail (the box below says where it gains)",
}


def calibration(root: Path = interpreter.PACKAGE_DIR) -> dict:
    """The calibration file's contents, or {} when it is absent or unreadable."""
    try:
        doc = json.loads((Path(root) / "backend" / "presets.json").read_text())
    except (OSError, ValueError):
        return {}
    return doc if isinstance(doc, dict) and isinstance(doc.get("presets"), dict) else {}


def preset_names(calib: dict) -> tuple[str, ...]:
    """The preset names of a calibration (``calibration()``), in file order: the top level's,
    then any that only a kind lists; ``FALLBACK_NAMES`` when it names none."""
    if not calib:
        return FALLBACK_NAMES
    kinds = calib.get("kinds")
    sections = [calib.get("presets"), *(k.get("presets") for k in (kinds.values() if isinstance(kinds, dict) else ())
                                        if isinstance(k, dict))]
    names: list[str] = []
    for section in sections:
        if isinstance(section, dict):
            names += [n for n, entry in section.items() if n and isinstance(entry, dict) and n not in names]
    return tuple(names) or FALLBACK_NAMES


def enum_items(calib: dict) -> tuple[tuple[str, str, str], ...]:
    """``(name, label, description)`` of each preset, the Quality enum's items."""
    return tuple((name, name.capitalize(), DESCRIPTIONS.get(name, f"The backend's {name.capitalize()} preset"))
                 for name in preset_names(calib))


def kind_for(lighting: str, env_path: str = "") -> str:
    """The calibration kind a capture is promised, decided as the backend's ``lighting_kind``
    does: 'environment' when a map lights it (an imported HDR, or one the run estimates),
    else 'point' (the capture's lights, a flash)."""
    if lighting in ("AUTO", "ESTIMATE", "RIG", "WORLD_RIG") or (lighting == "CAPTURED" and env_path):
        return "environment"
    return "point"


def kind_calibration(calib: dict, kind: str) -> tuple[dict, str]:
    """(entries, what they were measured on) for ``kind``: its own calibration when the
    file has one, else the point-lit one with a warning for an HDR-lit capture."""
    own = (calib.get("kinds") or {}).get(kind) if calib else None
    if isinstance(own, dict) and isinstance(own.get("presets"), dict):
        doc = {**own, "machine": calib.get("machine")}
        return doc, ("Times measured on an HDR-lit object" if kind == "environment"
                     else "Times measured on a point-lit object")
    if kind == "environment":
        return calib, "Times measured on a point-lit object; HDR-lit captures take longer"
    return calib, "Times measured on a point-lit object"


def describe(preset: str, calib: dict) -> str:
    """'~12 min, F1 0.91 on MACHINE' (and '(no gain over Draft)' for a dominated preset), or
    'not calibrated'."""
    entry = calib.get("presets", {}).get(preset) if calib else None
    if not isinstance(entry, dict):
        return "not calibrated"
    parts = []
    if isinstance(entry.get("expected_minutes"), (int, float)):
        parts.append(f"~{entry['expected_minutes']:.3g} min")
    if isinstance(entry.get("expected_f1"), (int, float)):
        parts.append(f"F1 {entry['expected_f1']:.2f}")
    if not parts:
        return "not calibrated"
    by = entry.get("dominated_by")
    if isinstance(by, str) and by:  # measured no more accurate than a cheaper preset here
        parts[-1] += f" (no gain over {by.capitalize()})"
    machine = calib.get("machine")
    return ", ".join(parts) + (f" on {machine}" if isinstance(machine, str) and machine else "")


PRESETS = enum_items(calibration())  # read once, when Blender registers the Quality enum
