"""The lighting a run fitted, read back for rendering other views of the same capture.

Both scorers of a run's held-out views take it from here: ``evaluate`` on a finished run's
folder (backend.metrics.evaluate, via :func:`from_run`: report.json and RUN/environment.exr)
and ``--track-accuracy`` during a run (backend.planning.tracking, via :func:`from_live`: the
run's lighting model and material). :func:`light_views` then lights the views:

- ``captured``: the views' own point lights and map, the map x the staged material's fitted
  light factor (the factor scales the environment only, as in the fit);
- ``estimate``: the fitted map (strength 1, rotation 0, Blender's World convention) x the
  light factor (1 once a stage's end has folded it into the map), and the views' own point
  lights (the estimate keeps them);
- ``flash``: one point light at each view's camera centre with the fitted intensity, no map.

Under ``estimate`` and ``flash`` the albedo is in the units of the scale convention
(backend.lighting.convention), so only this lighting renders the run's material at the
capture's brightness; views under another light (``relit``) need the albedo brought to the
truth's units first (``evaluate`` does so)."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..capture.model import Capture, Environment
from ..errors import InputError, require
from . import estimated_map, flash, summed_map

MODELS = ("captured", "estimate", "flash")


@dataclass(frozen=True)
class RunLighting:
    """What a run fitted: its lighting ``model`` and that model's parameters."""

    model: str = "captured"
    environment: Environment | None = None  # estimate: the fitted map
    intensity: np.ndarray | None = None  # flash: RGB radiant intensity, W/sr
    light_factor: float = 1.0  # the staged material's environment factor

    @property
    def convention(self) -> bool:
        """Whether the run's albedo is in the convention's units rather than the truth's."""
        return self.model in ("estimate", "flash")

    def describe(self) -> str:
        """One line for reports: the lighting the views were rendered under."""
        if self.model == "flash":
            value = float(self.intensity[0]) if np.ptp(self.intensity) == 0 else [round(float(x), 6) for x in self.intensity]
            return f"the run's fitted flash: {value} W/sr at each view's camera"
        factor = "" if self.light_factor == 1.0 else f" x light factor {self.light_factor:.4g}"
        if self.model == "estimate":
            frame = None if self.environment is None else self.environment.frame
            rig = {"camera": ", fixed to the camera",
                   summed_map.FRAME: f" plus {summed_map.RIG_FILENAME}, fixed to the camera"}.get(frame, "")
            return f"the run's fitted environment map ({estimated_map.FILENAME}{rig}){factor}"
        return f"the views' own lights{factor}"


def from_live(lighting, material) -> RunLighting:
    """During a run: ``lighting`` is its fitted lighting model (``Appearance.lighting``: an
    EstimatedEnvironment, a Flash, or None for the captured lighting), ``material`` its material."""
    factor = float(getattr(material, "light_factor", 1.0) or 1.0)
    if isinstance(lighting, flash.Flash):
        return RunLighting("flash", intensity=lighting.rgb_intensity)
    if isinstance(lighting, (estimated_map.EstimatedEnvironment, summed_map.SummedEnvironment)):
        return RunLighting("estimate", lighting.environment(), light_factor=factor)
    return RunLighting("captured", light_factor=factor)


def from_run(folder: str | Path) -> RunLighting:
    """A run folder's: report.json ``lighting`` and ``material.light_factor``, the map from
    RUN/environment.exr. A folder without a readable report (an interrupted run) is taken as
    captured lighting at factor 1."""
    folder = Path(folder)
    try:
        report = json.loads((folder / "report.json").read_text())
    except (OSError, ValueError):
        return RunLighting()
    lighting = report.get("lighting") or {}
    try:
        factor = float((report.get("material") or {}).get("light_factor") or 1.0)
    except (TypeError, ValueError, AttributeError):
        factor = 1.0
    model = str(lighting.get("model", "captured"))
    if model == "flash":
        value = np.asarray(lighting.get("intensity") if lighting.get("intensity") is not None else np.nan, np.float64)
        require(value.size in (1, 3) and bool(np.all(np.isfinite(value) & (value > 0))), folder / "report.json",
                "the flash run's report has no positive lighting.intensity", "re-run or resume the reconstruction")
        return RunLighting("flash", intensity=np.broadcast_to(value.reshape(-1), (3,)).copy())
    if model.startswith("environment map"):
        path = folder / str(lighting.get("file") or estimated_map.FILENAME)
        require(path.is_file(), path, "the run's estimated environment map is missing",
                "re-run or resume the reconstruction (it writes the map with every snapshot)")
        if lighting.get("frame") == summed_map.FRAME:
            rig = folder / str(lighting.get("rig_file") or summed_map.RIG_FILENAME)
            require(rig.is_file(), rig, "the run's estimated rig map is missing",
                    "re-run or resume the reconstruction (it writes the maps with every snapshot)")
            return RunLighting("estimate", Environment(path, 1.0, 0.0, "estimated", frame=summed_map.FRAME,
                                                       rig_path=rig), light_factor=factor)
        frame = "camera" if lighting.get("frame") == "camera" else "world"
        return RunLighting("estimate", Environment(path, 1.0, 0.0, "estimated", frame=frame), light_factor=factor)
    if model != "captured":
        raise InputError(folder / "report.json", f"unknown lighting model '{model}'",
                         f"a run's report names one of {', '.join(MODELS)}")
    return RunLighting("captured", light_factor=factor)


def light_views(views: Capture, fitted: RunLighting) -> Capture:
    """``views`` (frames of the capture the run fitted, or its held-out views) under the run's
    fitted lighting (the module docstring); a new Capture, ``views`` is left as it was."""
    if fitted.model == "flash":
        lit = dataclasses.replace(views, frames=[dataclasses.replace(f, lights=[]) for f in views.frames],
                                  environment=None)
        flash.place(lit, fitted.intensity)
        return lit
    env = fitted.environment if fitted.model == "estimate" else views.environment
    if env is not None and fitted.light_factor != 1.0:
        env = env.scaled(fitted.light_factor)
    return dataclasses.replace(views, environment=env)
