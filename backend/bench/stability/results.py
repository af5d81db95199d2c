"""What a stability case found: ``Result`` (one case) and ``StepLog`` (every gradient
evaluation of a run), and the limits the cases are held to."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
MEMORY_LIMIT_GB = 12.0
GRADIENT_TOLERANCE = 0.05  # relative error of AD against central finite differences
KNOWN = "known:0.6,0.6,0.6:0.2:0.4"


# -- results ------------------------------------------------------------------------------------------
@dataclass
class Result:
    """What one case did and whether it held up."""

    case: str
    steps: int = 0  # optimisation steps run (gradient evaluations)
    caught: int = 0  # steps the loop skipped (non-finite values, invalid geometry), from report.json
    final_loss: float | None = None
    peak_rss_gb: float | None = None
    seconds: float = 0.0
    problems: list[str] = field(default_factory=list)
    notes: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return not self.problems

    def check(self, condition: bool, problem: str) -> bool:
        if not condition:
            self.problems.append(problem)
        return bool(condition)

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "passed": self.passed}


@dataclass
class StepLog:
    """Every gradient evaluation of a run, recorded by :func:`recording`."""

    losses: list[float] = field(default_factory=list)
    grad_norms: list[float] = field(default_factory=list)
    nonfinite_steps: int = 0  # evaluations whose loss or gradients were not finite (injected included)
    problems: list[str] = field(default_factory=list)  # non-finite inputs, material values out of range
    validation: list[float] = field(default_factory=list)
    level_meshes: list[dict] = field(default_factory=list)  # checks of each level's starting mesh
    step_intersections: list[int] = field(default_factory=list)  # self-intersecting faces at each step

    def flag(self, problem: str) -> None:
        if len(self.problems) < 5:
            self.problems.append(problem)
