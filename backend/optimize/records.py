"""Typed records of a run: ``LevelRecord`` (one geometry level or polish round) and
``RunState`` (where a run stands: what --resume restores and report.json reports).

Their JSON forms are those of state/state.json and report.json (docs/protocol.md)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

from ..geometry.mesh import Mesh
from ..geometry.simplify import FaceBudget


@dataclass
class LevelRecord:
    """One geometry level (or, with ``polish``, one polish round) as report.json lists it."""

    level: int
    size: int  # long side of its images, pixels
    faces: int
    iterations: int
    loss_start: float  # validation loss before its first step
    loss: float  # best validation loss
    step_final: float  # its last vertex step, in units of its first
    material_frozen_at: int | None  # the step at which joint material steps stopped
    seconds: float
    elapsed: float  # run time at its end
    metrics: dict | None = None  # geometry metrics against the ground truth (--track-metrics)
    polish: bool = False
    material: list[dict] | None = None  # the material cycles run after it
    remesh: dict | None = None  # the re-mesh check that followed it
    shadow_samples: dict | None = None  # the shadow-gradient samples it afforded (optimize.shadow_samples)

    OPTIONAL = ("metrics", "polish", "material", "remesh", "shadow_samples")

    def add_cycle(self, cycle: dict) -> None:
        self.material = (self.material or []) + [cycle]

    @property
    def last_cycle_seconds(self) -> float | None:
        return self.material[-1]["seconds"] if self.material else None

    def to_json(self) -> dict:
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in self.OPTIONAL}
        out.update({name: getattr(self, name) for name in self.OPTIONAL if getattr(self, name)})
        return out

    @classmethod
    def from_json(cls, data: dict) -> "LevelRecord":
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})


@dataclass
class RunState:
    """Where a run stands. ``phase`` is where a resume restarts: "level", "transition",
    "materials", "polish" (or "done")."""

    mesh: Mesh | None = None
    level: int = 0
    iteration: int = 0  # optimisation steps over all levels
    level_iteration: int = 0  # steps of the current level (not saved)
    phase: str = "level"
    polished: int = 0  # polish rounds run
    budget: FaceBudget | None = None
    levels: list[LevelRecord] = field(default_factory=list)
    levels_ended: str | None = None  # why the coarse-to-fine levels ended
    skipped: int = 0
    timings: dict[str, float] = field(default_factory=dict)
    init: dict = field(default_factory=dict)
    seconds_before: float = 0.0  # run time of the runs this one resumes
    appearance: dict | None = None
    material_kind: str | None = None
    accuracy: dict | None = None  # the held-out series so far (planning/tracking.py; --track-accuracy)
    level_limit: int | None = None  # steps that end a level, from the run's plan (planning/time_plan.py)
    cameras: dict | None = None  # the camera corrections (optimize/camera_fit.py; --refine-cameras)

    def timed(self, name: str, start: float) -> None:
        """Charge the time since ``start`` (perf_counter) to ``timings[name]``."""
        self.timings[name] = round(self.timings.get(name, 0.0) + time.perf_counter() - start, 3)

    @property
    def last_loss(self) -> float | None:
        return self.levels[-1].loss if self.levels else None

    def to_json(self, seconds: float, appearance: dict | None) -> dict:
        """The resumable state (RunFolder.save_state): the mesh arrays plus JSON fields;
        ``appearance``: the material schedule's position (Appearance.state)."""
        return {"vertices": self.mesh.vertices, "faces": self.mesh.faces, "level": self.level,
                "iteration": self.iteration, "phase": self.phase, "polished": self.polished,
                "budget": self.budget.state(), "levels": [lv.to_json() for lv in self.levels],
                "levels_ended": self.levels_ended, "skipped": self.skipped, "timings": self.timings,
                "init": self.init, "seconds": round(seconds, 3), "appearance": appearance,
                "material_kind": self.material_kind, "accuracy": self.accuracy, "level_limit": self.level_limit,
                "cameras": self.cameras}

    @classmethod
    def from_json(cls, state: dict) -> "RunState":
        return cls(mesh=Mesh(state["vertices"], state["faces"]), level=state["level"], iteration=state["iteration"],
                   phase=state["phase"], polished=state.get("polished", 0), budget=FaceBudget(**state["budget"]),
                   levels=[LevelRecord.from_json(lv) for lv in state["levels"]],
                   levels_ended=state.get("levels_ended"), skipped=state["skipped"], timings=state["timings"],
                   init=state["init"], seconds_before=state["seconds"], appearance=state.get("appearance"),
                   material_kind=state.get("material_kind"), accuracy=state.get("accuracy"),
                   level_limit=state.get("level_limit"), cameras=state.get("cameras"))
