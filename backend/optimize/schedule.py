"""When to stop a level, when to stop refining, and the image size of each level.

Convergence is judged on the loss over a fixed validation subset of views, rendered with a
fixed seed, so two evaluations differ only through the surface. A level has *plateaued*
when ``patience`` evaluations in a row fail to improve the best loss by more than
``tolerance`` (relative; default 0.5 %, well above the seed-fixed Monte Carlo jitter of a
converged mesh, well below the gains of a level that is still moving). The run stops
refining when a level at the same image size as the previous one improves the best
validation loss by less than ``level_tolerance`` (default 0.3 %: levels that still gain
accuracy improve the loss by more)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class Plateau:
    tolerance: float = 0.005
    patience: int = 3
    best: float = math.inf
    stale: int = 0
    history: list[float] = field(default_factory=list)

    def update(self, loss: float) -> bool:
        """Record a validation loss; True when it is a new best (by more than the tolerance)."""
        self.history.append(loss)
        if loss < self.best * (1 - self.tolerance):
            self.best, self.stale = loss, 0
            return True
        self.stale += 1
        return False

    @property
    def converged(self) -> bool:
        return self.stale >= self.patience


def level_size(level: int, coarse: int, finest: int) -> int:
    """Long side in pixels of level ``level``: doubling from ``coarse`` up to ``finest``."""
    return int(min(finest, coarse * 2 ** level))


def keeps_improving(previous, current, tolerance: float) -> bool:
    """Whether another level is worth running after ``current`` (LevelRecords: size, loss)."""
    if previous is None or previous.size != current.size:
        return True
    return current.loss < previous.loss * (1 - tolerance)
