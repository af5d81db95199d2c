"""``Remaining``: a run's time left, re-estimated while it runs from the plan's phases and
the pace each finished phase measured (the model: ``Remaining``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..events import read_log

END_S = 4.0  # the last check and the outputs after the last phase


@dataclass
class Phase:
    """One planned phase: ``kind`` level | cycle | final | polish; ``units`` its planned steps
    (level, polish round) or iterations (cycle); ``unit_s`` the planned seconds per unit;
    ``cap`` the most units it may run; ``count`` how many such phases (final cycles, rounds)."""

    kind: str
    units: float
    unit_s: float
    cap: float | None = None
    count: float = 1.0
    cycle_units: float = 0.0  # polish: its refinement cycle's iterations
    cycle_s: float = 0.0  # polish: planned seconds per refinement-cycle iteration

    @property
    def seconds(self) -> float:
        return self.paced(1.0, 1.0)

    def paced(self, step: float, cycle: float, count: float | None = None) -> float:
        """Seconds of ``count`` (default ``self.count``) such phases, their steps at ``step``
        times the planned pace and their material iterations at ``cycle`` times it."""
        unit = cycle if self.kind in ("cycle", "final") else step
        n = self.count if count is None else count
        return n * (self.units * self.unit_s * unit + self.cycle_units * self.cycle_s * cycle)

    def to_json(self) -> dict:
        return {k: float(f"{v:.6g}") if isinstance(v, float) else v for k, v in self.__dict__.items()}


@dataclass
class _Current:
    kind: str  # level | cycle | polish
    start: float
    planned_units: float
    planned_unit_s: float
    cap: float | None
    done: float = 0.0
    at: float = 0.0  # clock at the last report of ``done``
    stage: str = ""


@dataclass
class Remaining:
    """The live estimate; ``phases`` from ``PresetPlan.phases`` (empty: no estimate).

    Before the first step the plan (planning/time_plan.py) predicts every phase of the run: each
    level's geometry steps and its material cycle, the long material cycles on the converged
    geometry, the polish rounds. What it cannot know are the counts that end on convergence
    (steps per level, final cycles, polish steps) and how much a step costs once the material
    is spatially varying and the effects are re-decided. So while the run goes, each phase's
    measured pace replaces the plan's guess. With ``t`` now and the phases in order,

        remaining(t) = left(current, t) + sum over later phases q of planned(q) * pace(kind of q) + END_S

    - ``left(current, t)``: the current phase's units still to go (geometry or polish steps,
      material iterations) times the seconds per unit measured in it, less the time since its
      last report. Units still to go are the plan's count less those done; past the plan's count,
      half of what its cap still allows (a level that has not converged by its expected length
      goes on for a while, and may run to its cap).
    - ``pace(kind)``: measured over planned seconds per unit in the latest finished phase of the
      same kind (``step``: geometry levels and polish rounds; ``cycle``: material cycles), 1 before
      there is one. The latest, not the mean: a step costs more at each level (finer images, more
      faces, a varying material) by more than the plan's timing of the initial mesh shows.
    - The final cycles are the plan's mean count; once a run has gone past it, the cycle under
      way is taken as the last. Each polish round adds its refinement cycle. Cycles before level
      0 (the lighting fitted first) come before the plan and are not counted.

    With a time budget the remaining time is at most what the budget leaves (and the outputs).
    Events drive it (``observe``: ``stage`` and ``progress`` events as the run emits them, with
    the clock's time), so ``bench plan --replan`` replays finished runs through the same code
    (docs/results.md).
    """

    phases: list[Phase] = field(default_factory=list)
    budget_s: float | None = None
    index: int = -1  # the planned phase the run is in (-1: before level 0)
    current: _Current | None = None
    pace: dict = field(default_factory=lambda: {"step": 1.0, "cycle": 1.0})
    final_done: int = 0
    rounds_done: int = 0
    in_polish_cycle: bool = False
    ended: bool = False

    @classmethod
    def from_plan(cls, plan, budget_s: float | None = None) -> "Remaining":
        """From a PresetPlan or its JSON (``phases``); inactive when it has none."""
        phases = getattr(plan, "phases", None)
        if phases is None and isinstance(plan, dict):
            phases = [Phase(**p) for p in plan.get("phases") or []]
        return cls(list(phases or []), budget_s)

    @property
    def active(self) -> bool:
        return bool(self.phases) and not self.ended

    # -- events --------------------------------------------------------------------------------
    def observe(self, event: str, fields: dict, now: float) -> None:
        if not self.phases:
            return
        if event == "stage":
            self._stage(str(fields.get("stage", "")), fields, now)
        elif event == "progress" and self.current is not None and fields.get("stage") == self.current.stage:
            if fields.get("iteration") is not None:
                self.current.done, self.current.at = float(fields["iteration"]), now

    def _close(self, now: float) -> None:
        """The current phase ends: its measured pace (per unit, against the plan's)."""
        cur = self.current
        if cur is not None and cur.done >= 3 and cur.planned_unit_s > 0:
            kind = "cycle" if cur.kind == "cycle" else "step"
            self.pace[kind] = (now - cur.start) / cur.done / cur.planned_unit_s
        self.current = None

    def _next(self, kind: str) -> int:
        """The index of the next planned phase of ``kind`` after the current one (or the last such)."""
        for i in range(self.index + 1, len(self.phases)):
            if self.phases[i].kind == kind:
                return i
        found = [i for i, p in enumerate(self.phases) if p.kind == kind]
        return found[-1] if found else self.index

    def _stage(self, stage: str, fields: dict, now: float) -> None:
        self._close(now)  # a re-mesh ends the level's cycle: its own seconds are not a cycle's pace
        if stage in ("remesh", "refine", "init", "resume"):
            return
        if stage == "material:check":
            self.ended = True
            return
        if stage == "geometry":
            levels = [i for i, p in enumerate(self.phases) if p.kind == "level"]
            level = fields.get("level")  # a resumed run starts its level again: found by number
            self.index = self._next("level") if level is None or not levels else levels[min(int(level), len(levels) - 1)]
            p = self.phases[self.index]
            self.current = _Current("level", now, p.units, p.unit_s, p.cap, at=now, stage=stage)
        elif stage == "polish":
            self.index = self._next("polish")
            p = self.phases[self.index]
            self.in_polish_cycle = False
            self.current = _Current("polish", now, p.units, p.unit_s, p.cap, at=now, stage=stage)
        elif stage.startswith("material"):
            if self.index < 0:  # the lighting fitted before level 0
                return
            here = self.phases[self.index]
            if here.kind == "level":  # the level's own cycle
                if self.index + 1 >= len(self.phases) or self.phases[self.index + 1].kind != "cycle":
                    return  # one the plan has not
                self.index += 1
                p = self.phases[self.index]
                units, unit_s = p.units, p.unit_s
            elif here.kind == "polish":
                if not self.in_polish_cycle:  # the round's refinement (one or more cycles)
                    self.in_polish_cycle, self.rounds_done = True, self.rounds_done + 1
                units, unit_s = here.cycle_units, here.cycle_s
            else:  # a cycle on the converged geometry
                if here.kind != "final":
                    self.index = self._next("final")
                    self.final_done = 0
                self.final_done += 1
                p = self.phases[self.index]
                units, unit_s = p.units, p.unit_s
            self.current = _Current("cycle", now, units, unit_s, None, at=now, stage=stage)

    # -- the estimate --------------------------------------------------------------------------
    def _left(self, now: float) -> float:
        cur = self.current
        if cur is None:
            return 0.0
        units = cur.planned_units - cur.done
        if units <= 0:
            units = 0.5 * max((cur.cap or cur.done) - cur.done, 0.0)
        if cur.done >= 3 and cur.at > cur.start:
            rate = (cur.at - cur.start) / cur.done
        else:
            rate = cur.planned_unit_s * self.pace["cycle" if cur.kind == "cycle" else "step"]
        return max(units * rate - (now - cur.at), 0.0)

    def _later(self) -> float:
        step, cycle = self.pace["step"], self.pace["cycle"]
        total = 0.0
        here = self.phases[self.index] if self.index >= 0 else None
        if here is not None and here.kind == "final":
            total += here.paced(step, cycle, max(here.count - self.final_done, 0.0))
        if here is not None and here.kind == "polish":
            rounds = max(here.count - self.rounds_done - (0 if self.in_polish_cycle else 1), 0.0)
            if not self.in_polish_cycle:  # this round's refinement cycle
                total += here.cycle_units * here.cycle_s * cycle
            total += here.paced(step, cycle, rounds)
        return total + sum(p.paced(step, cycle) for p in self.phases[self.index + 1:])

    def seconds(self, now: float) -> float | None:
        """Seconds left at clock time ``now``; None when there is no estimate."""
        if not self.phases:
            return None
        if self.ended:
            return END_S
        left = self._left(now) + self._later() + END_S
        if self.budget_s:
            left = min(left, max(self.budget_s - now, 0.0) + END_S)
        return left


def resumed(events_path, budget_s: float | None = None) -> Remaining | None:
    """The time left of a resumed run: the plan of the process that began it (its last
    ``preset`` event with phases in ``events_path``), with every event since replayed, so that
    the phases done and their pace carry over; None without such a plan."""
    events = read_log(events_path)
    planned = [i for i, e in enumerate(events) if e.get("event") == "preset" and (e.get("plan") or {}).get("phases")]
    if not planned:
        return None
    remaining = Remaining.from_plan(events[planned[-1]]["plan"], budget_s)
    for e in events[planned[-1]:]:
        remaining.observe(str(e.get("event")), e, float(e.get("time") or 0.0))
    remaining.current, remaining.ended = None, False  # the phase it was in starts again
    return remaining
