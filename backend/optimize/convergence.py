"""When a level has converged, whether another level is worth running, each level's image
size, and what the level a time budget cut off was expected to buy (the rules: ``Plateau``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class Plateau:
    """A level's validation losses: ``update`` says whether one is a new best, ``converged``
    whether ``patience`` evaluations in a row were not.

    Convergence is judged on the loss over a fixed validation subset of views, rendered with a
    fixed seed, so two evaluations differ only through the surface. A level has *plateaued*
    when ``patience`` evaluations in a row fail to improve the best loss by more than
    ``tolerance`` (relative; default 0.5 %, well above the seed-fixed Monte Carlo jitter of a
    converged mesh, well below the gains of a level that is still moving). The run stops
    refining when a level at the same image size as the previous one improves the best
    validation loss by less than ``level_tolerance`` (default 0.3 %: levels that still gain
    accuracy improve the loss by more).
    """

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


def levels_end(config, state, budget, record) -> str | None:
    """Why no level follows ``record`` (the level just run; ``state``: the RunState that holds
    it, ``budget``: the run's Budget), or None when another one does."""
    c, s = config, state
    previous = s.levels[-2] if len(s.levels) > 1 else None
    if budget.out(budget.geometry_reserve()):
        return "iterations" if budget.out_of_iterations() else "time budget"
    if s.level + 1 >= c.max_levels:
        return "max levels"
    if s.level + 1 >= c.min_levels and not keeps_improving(previous, record, c.level_tolerance):
        return "converged"
    if s.budget.limit > c.max_faces:
        return "max faces"
    return None


def next_level(levels: list, levels_ended: str | None, gains: list[dict], size: int) -> dict | None:
    """What the level a time budget cut off was expected to buy: an extrapolation from the
    last level run (its held-out PSNR gain when tracked, its validation-loss drop always).
    None unless the time budget ended the levels."""
    geometric = [lv for lv in levels if not lv.polish]
    if levels_ended != "time budget" or not geometric:
        return None
    last = geometric[-1]
    drop = (last.loss_start - last.loss) / last.loss_start if last.loss_start > 0 else None
    gain = next((g for g in gains if g["level"] == last.level), None)
    seconds = gain["seconds"] if gain is not None else last.seconds
    out = {"level": last.level + 1, "size": size, "extrapolated": True,
           "basis": f"level {last.level}, the last one run ({seconds:.0f} s with its stages)",
           "validation_loss_drop": None if drop is None else round(drop, 4),
           "psnr_gain_db": None if gain is None else gain["psnr_gain_db"]}
    bought = (f"about {gain['psnr_gain_db']:+.2f} dB held-out PSNR" if gain is not None else
              f"about {100 * drop:.1f} % lower validation loss" if drop is not None else "an unknown gain")
    out["line"] = (f"the time budget ended the levels after level {last.level}: level {last.level + 1} "
                   f"({size} px) was expected to buy {bought} (extrapolated: level {last.level}'s own gain, "
                   f"in {seconds:.0f} s)")
    return out
