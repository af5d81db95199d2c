"""Shadow-gradient samples held within a step-cost ratio, timed again at every level
(the controller: ``ShadowSamples``)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

RATIO = 1.9
MIN_SPPI = 4
TIMED = 3  # timed steps of each kind
CORRECTIONS = 1  # times the kept count may be derived again from its own steps


@dataclass
class ShadowSamples:
    """The schedule of one level. ``full``: the settings' sppi.

    A projective integrator's indirect-visibility (shadow) term is estimated with ``sppi``
    unguided samples per pixel (``render.effects.SHADOW_SPPI``). What one sample costs grows with
    the image, the mesh and the path depth, so a count that adds a quarter to a 64 px step can
    double a 160 px one. The effects decision says *whether* shadow gradients pay; this controller
    sets *how many* samples each level affords.

    At the start of every level or polish round whose settings carry shadow gradients, the level's
    own geometry steps are timed, alternately with the full count ``n`` and with none (real steps:
    a few of the level's hundreds go without the shadow term; the first step of each kind is
    untimed, it compiles kernels). With t(k) the median step time at k samples, and the cost of
    a step taken as linear in k (measured: docs/notes/2026-11-24-hdr-shadow-gradients.md),

        r = t(n) / t(0),        sppi = min(n, max(n_min, floor(n (ratio - 1) / (r - 1))))

    so that t(sppi) / t(0) <= ``ratio``. ``ratio`` = 1.9 leaves the margin of the timing's noise
    below the 2x a step with shadow gradients may cost; ``n_min`` keeps the term from vanishing
    (its noise falls as 1/sppi, and the optimiser averages it over steps).

    The linear model is then checked on the level's own steps at the kept count: once ``timed``
    of them are timed (after one untimed compile), the achieved ratio a = t(sppi) / t(0) is
    measured. When a > ``ratio`` and more than ``n_min`` samples are kept, the count is derived
    once more from the line through t(0) and t(sppi),

        sppi' = max(n_min, min(sppi - 1, floor(sppi (ratio - 1) / (a - 1)))),

    and the achieved ratio is measured again at sppi'. The level's record carries the achieved
    ratio over all its steps at the final count, so every run states what its shadow gradients
    cost, not only what they were predicted to cost.
    """

    full: int
    ratio: float = RATIO
    min_sppi: int = MIN_SPPI
    timed: int = TIMED
    chosen: int | None = None
    corrections: list = field(default_factory=list)  # [{chosen, achieved_ratio}] replaced after their own steps
    seconds: dict = field(default_factory=lambda: {"full": [], "none": []})
    kept_seconds: list = field(default_factory=list)  # geometry steps at ``chosen``, the compile left out
    checked: bool = False  # the achieved ratio has been measured at ``chosen``
    _step: int = 0
    _kept_steps: int = 0

    @property
    def active(self) -> bool:
        return self.full > 0

    def next_count(self) -> int:
        """The sppi of the next geometry step."""
        if self.chosen is not None:
            return self.chosen
        return self.full if not self.active or self._step % 2 == 0 else 0

    def record(self, sppi: int, seconds: float) -> bool:
        """Record a geometry step taken at ``sppi`` in ``seconds``; True when this settles the
        count, checks it or changes it (the caller then sets ``chosen`` and reports)."""
        if not self.active:
            return False
        if self.chosen is not None:
            return self._record_kept(float(seconds))
        step, self._step = self._step, self._step + 1
        if step >= 2:  # steps 0 and 1 compile the two configurations' kernels
            self.seconds["full" if sppi else "none"].append(float(seconds))
        if min(len(v) for v in self.seconds.values()) < self.timed:
            return False
        self.chosen = count_for_ratio(self.full, self.measured_ratio, self.ratio, self.min_sppi)
        return True

    def _record_kept(self, seconds: float) -> bool:
        step, self._kept_steps = self._kept_steps, self._kept_steps + 1
        if step == 0 and self.chosen not in (0, self.full):
            return False  # a new count compiles its kernels
        self.kept_seconds.append(seconds)
        if self.checked or len(self.kept_seconds) < self.timed:
            return False
        self.checked = True
        achieved = self.achieved_ratio
        if (achieved is None or achieved <= self.ratio or self.chosen <= self.min_sppi
                or len(self.corrections) >= CORRECTIONS):
            return True
        self.corrections.append({"chosen": self.chosen, "achieved_ratio": round(achieved, 3)})
        self.chosen = max(self.min_sppi, min(self.chosen - 1,
                                             math.floor(self.chosen * (self.ratio - 1.0) / (achieved - 1.0) + 1e-9)))
        self.kept_seconds, self._kept_steps, self.checked = [], 0, False
        return True

    @property
    def achieved_ratio(self) -> float | None:
        """Median step at the kept count over median step without shadow gradients."""
        if not self.kept_seconds or not self.seconds["none"]:
            return None
        return float(np.median(self.kept_seconds) / max(np.median(self.seconds["none"]), 1e-9))

    @property
    def measured_ratio(self) -> float | None:
        if not self.seconds["full"] or not self.seconds["none"]:
            return None
        return float(np.median(self.seconds["full"]) / max(np.median(self.seconds["none"]), 1e-9))

    def expected_ratio(self) -> float | None:
        """The ratio the line predicts at ``chosen``: through the last count timed on its own
        steps when the count was corrected, else through ``full``."""
        if self.corrections:
            last = self.corrections[-1]
            return 1.0 + (last["achieved_ratio"] - 1.0) * self.chosen / last["chosen"]
        r = self.measured_ratio
        if r is None or self.chosen is None:
            return None
        return 1.0 + (r - 1.0) * self.chosen / self.full

    def to_json(self) -> dict:
        skip = ("seconds", "kept_seconds")
        out = {k: v for k, v in asdict(self).items() if not k.startswith("_") and k not in skip}
        medians = {k: round(float(np.median(v)), 4) if v else None for k, v in self.seconds.items()}
        measured, expected, achieved = self.measured_ratio, self.expected_ratio(), self.achieved_ratio
        out.update(step_seconds=medians["full"], base_seconds=medians["none"],
                   measured_ratio=None if measured is None else round(measured, 3),
                   expected_ratio=None if expected is None else round(expected, 3),
                   kept_steps=len(self.kept_seconds),
                   kept_seconds=round(float(np.median(self.kept_seconds)), 4) if self.kept_seconds else None,
                   achieved_ratio=None if achieved is None else round(achieved, 3))
        return out


def count_for_ratio(full: int, measured: float, ratio: float = RATIO, minimum: int = MIN_SPPI) -> int:
    """The most samples (at most ``full``) whose step stays within ``ratio`` of one without,
    given the ratio ``measured`` at ``full`` samples and a cost linear in the count."""
    if measured <= ratio:
        return full
    return int(min(full, max(minimum, math.floor(full * (ratio - 1.0) / (measured - 1.0) + 1e-9))))


def charged_seconds(full_seconds: float, base_seconds: float, full: int, ratio: float = RATIO,
                    minimum: int = MIN_SPPI) -> float:
    """A step's expected time once a level keeps its samples: ``full_seconds`` timed at ``full``
    samples, ``base_seconds`` without; the cost linear in the count, as above."""
    kept = count_for_ratio(full, full_seconds / max(base_seconds, 1e-9), ratio, minimum)
    return base_seconds + (full_seconds - base_seconds) * kept / full
