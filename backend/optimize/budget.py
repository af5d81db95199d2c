"""``Budget``: the run's clock and every limit on it: the time budget, the iteration cap, the
shares of the time held back for the material stages on the final geometry and for what
follows the polish rounds (staged materials only), and the seconds held back for writing the
results.

The budget is the wall clock of the whole command: the clock starts when the command starts
(``started``), so loading, the capture written from a video, initialisation, the plan, the
held-out scoring, metrics against a ground-truth mesh, re-meshes and the results all count."""

from __future__ import annotations

import time

from .records import RunState

# shares of a time budget: the geometry levels leave GEOMETRY_RESERVE to the final material
# stages and polish rounds (enough for one polish round); polish rounds leave POLISH_RESERVE
# to what follows them until a cycle on the final mesh has been timed, then POLISH_RESERVE_CYCLES
# of that cycle's length (the refinement cycle, the specular check and the outputs)
GEOMETRY_RESERVE = 0.4
POLISH_RESERVE = 0.05
POLISH_RESERVE_CYCLES = 1.75
# the results (the last snapshot, result.ply, the textures and result.glb, report.json) are
# written after the budget's last step: held back as this many times the last snapshot's
# seconds, and at least FINISH_MIN_S
FINISH_SNAPSHOTS = 3.0
# the final texture stage at the frames' own size (optimize.texture_stage), when it runs: this
# share of a time budget is held back from the material stages and polish rounds for it
TEXTURE_RESERVE = 0.1
FINISH_MIN_S = 2.0


def polish_share(last_cycle_seconds: float | None, budget_s: float | None) -> float:
    """The share of a time budget of ``budget_s`` that polish rounds leave to what follows
    them: ``POLISH_RESERVE_CYCLES`` x ``last_cycle_seconds`` (the last material cycle on the
    final mesh) / ``budget_s``, or ``POLISH_RESERVE`` before a cycle has been timed."""
    if not (budget_s and last_cycle_seconds is not None):
        return POLISH_RESERVE
    return POLISH_RESERVE_CYCLES * last_cycle_seconds / budget_s


class Budget:
    """The clock: seconds since ``started`` (a ``time.perf_counter()`` reading: the command's
    start; default now), plus those of the runs this one resumes. ``staged``: whether a
    material schedule runs (the reserves apply only then)."""

    def __init__(self, config, state: RunState, staged: bool, started: float | None = None):
        self.config, self.state, self.staged = config, state, staged
        self.t0 = time.perf_counter() if started is None else started
        self.remaining = None  # planning.remaining.Remaining, once the run has a plan
        self.snapshot_s = 0.0  # what the last snapshot took to write
        self.metrics_s = 0.0  # what scoring the mesh against a true one took, when the run does
        self.texture_share = 0.0  # the share held back for the texture stage until it starts

    def finish_s(self) -> float:
        """Seconds held back for writing the results once the last step has run (and, until
        it starts, for the texture stage: ``texture_share`` of the budget)."""
        held = self.texture_share * (self.config.time_budget_s or 0.0)
        return max(FINISH_MIN_S, FINISH_SNAPSHOTS * self.snapshot_s) + self.metrics_s + held

    def elapsed(self) -> float:
        return self.state.seconds_before + time.perf_counter() - self.t0

    def fraction(self) -> float:
        """The share of the run done, for the progress events' ETA: elapsed / (elapsed + the time
        left) once the run has a plan (``remaining``), else from its steps or budget."""
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
        return bool((c.time_budget_s and self.elapsed() >= c.time_budget_s * (1.0 - reserve) - self.finish_s())
                    or (c.iterations and self.state.iteration >= c.iterations))

    def out_of_iterations(self) -> bool:
        return bool(self.config.iterations and self.state.iteration >= self.config.iterations)

    def seconds_left(self) -> float | None:
        """Seconds until the time budget's end, the results' share held back (``finish_s``);
        None without a time budget."""
        budget = self.config.time_budget_s
        return max(0.0, budget - self.elapsed() - self.finish_s()) if budget else None

    def fits(self, seconds: float) -> bool:
        """Whether work of ``seconds`` still ends within the time budget."""
        left = self.seconds_left()
        return left is None or seconds <= left

    def geometry_reserve(self) -> float:
        """The share the geometry levels leave to the material stages on the final geometry
        (the texture stage's share, held back in ``finish_s``, comes out of it)."""
        return max(0.0, GEOMETRY_RESERVE - self.texture_share) if self.staged else 0.0

    def polish_reserve(self) -> float:
        """The share polish rounds leave to what follows them (``polish_share``), measured on the
        last material cycle on the final mesh once there is one."""
        if not self.staged:
            return 0.0
        last = self.state.levels[-1].last_cycle_seconds if self.state.levels else None
        return polish_share(last, self.config.time_budget_s)
