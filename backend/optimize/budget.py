"""``Budget``: the run's clock and every limit on it (time budget, iteration cap, the shares
of the time held back for the material stages and for what follows polish rounds)."""

from __future__ import annotations

import time
from contextlib import contextmanager

from .records import RunState


class Budget:
    """The clock: seconds since the start, plus those of the runs this one resumes, less the
    time spent on tracking metrics (not charged to the budget)."""

    def __init__(self, config, appearance, state: RunState):
        self.config, self.appearance, self.state = config, appearance, state
        self.t0 = time.perf_counter()
        self.excluded = 0.0
        self.remaining = None  # optimize/remaining.Remaining, once the run has a plan

    def elapsed(self) -> float:
        return self.state.seconds_before + time.perf_counter() - self.t0 - self.excluded

    @contextmanager
    def uncharged(self):
        """Time spent inside is not charged to the budget (metrics against the ground truth)."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.excluded += time.perf_counter() - start

    def fraction(self) -> float:
        """The share of the run done, for the progress events' ETA: elapsed / (elapsed + the time
        left) once the run has a plan (optimize/remaining.py), else from its steps or budget."""
        c, s = self.config, self.state
        elapsed = self.elapsed()
        left = None if self.remaining is None else self.remaining.seconds(elapsed)
        if left is not None:
            return min(0.999, elapsed / max(elapsed + left, 1e-9))
        estimates = []
        if c.iterations:
            estimates.append(s.iteration / c.iterations)
        if c.time_budget_s:
            estimates.append(self.elapsed() / c.time_budget_s)
        if not estimates:
            estimates.append((s.level + min(1.0, s.level_iteration / c.level_iterations)) / c.max_levels)
        return min(0.999, max(estimates))

    def out(self, reserve: float = 0.0) -> bool:
        """Whether the run is out of time or steps; ``reserve``: the share of the time budget
        held back (``geometry_reserve``, ``polish_reserve``)."""
        c = self.config
        return bool((c.time_budget_s and self.elapsed() >= c.time_budget_s * (1.0 - reserve))
                    or (c.iterations and self.state.iteration >= c.iterations))

    def out_of_iterations(self) -> bool:
        return bool(self.config.iterations and self.state.iteration >= self.config.iterations)

    def fits(self, seconds: float) -> bool:
        """Whether work of ``seconds`` still ends within the time budget."""
        budget = self.config.time_budget_s
        return not (budget and self.elapsed() + seconds > budget)

    def geometry_reserve(self) -> float:
        """The share the geometry levels leave to the material stages on the final geometry."""
        return self.appearance.geometry_reserve()

    def polish_reserve(self) -> float:
        """The share polish rounds leave to one material cycle, the specular check and the
        outputs, measured on the last material cycle on the final mesh once there is one."""
        last = self.state.levels[-1].last_cycle_seconds if self.state.levels else None
        return self.appearance.polish_reserve(last, self.config.time_budget_s)
