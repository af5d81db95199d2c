"""What an optional light-transport effect costs per geometry step and what it changes in
the step: the paired probe the effects decision weighs (the maths: ``measure``)."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from .shadow_samples import RATIO as SHADOW_RATIO
from .steps import LaplacianSystem

# the most an effect's step is charged: shadow-gradient samples are cut per level to this ratio
CAPS = {"shadows": SHADOW_RATIO}


@dataclass
class EffectCost:
    """One candidate's measured cost and need (see ``measure``)."""

    effect: str
    seconds: float  # median geometry step with the effect
    base_seconds: float  # median geometry step without it
    share: float  # noise-corrected relative change of the smoothed gradient
    noise: float  # relative seed-to-seed spread of the effect's term (rms |d_k - mean d| / |g|)
    z: float  # significance of |E d|^2 against the spread of its pair products
    pays: bool = False
    cap: float | None = None  # the ratio the runs hold this effect's steps to (CAPS)

    @property
    def ratio(self) -> float:
        return self.seconds / max(self.base_seconds, 1e-9)

    @property
    def charged(self) -> float:
        """The step-time ratio the selection charges: measured, at most ``cap``."""
        return self.ratio if self.cap is None else min(self.ratio, self.cap)

    def to_json(self) -> dict:
        out = asdict(self)
        out.update(ratio=round(self.ratio, 3), charged=round(self.charged, 3), seconds=round(self.seconds, 4),
                   base_seconds=round(self.base_seconds, 4), share=round(self.share, 5), noise=round(self.noise, 5), z=round(self.z, 2))
        return out


@dataclass
class CostRule:
    value: float = 0.1  # gradient share an effect must remove per unit of extra step time
    min_share: float = 0.01  # below this share an effect changes nothing worth a decision
    z_score: float = 2.0
    seeds: tuple[int, ...] = (101, 202, 303)

    def pays(self, cost: EffectCost) -> bool:
        return cost.z >= self.z_score and cost.share >= max(self.min_share, self.value * (cost.charged - 1.0))


def _smoothed(system: LaplacianSystem, grad: np.ndarray) -> np.ndarray:
    return system.solve(np.asarray(grad, np.float64))


def measure(gradient, candidates: dict[str, object], base, faces: np.ndarray, n_vertices: int,
            lambda_: float, rule: CostRule | None = None) -> dict[str, EffectCost]:
    """Cost and share of each candidate configuration against ``base``.

    ``gradient(config, seed) -> dL/dv (V, 3)`` takes one geometry step's gradient (the probe
    views, the configuration's render settings); ``candidates`` maps an effect name to its
    configuration. Returns {effect: EffectCost} with ``pays`` set by ``rule``.

    Candidates are the effects whose cost grows the geometry step: shadow (indirect-silhouette)
    gradients, and one more bounce than the decision keeps. For each, on a few probe views, the
    probe takes geometry gradients with the current decision (``base``) and with the effect
    added, in the optimiser's smoothed space g~ = (I + lambda L)^-1 dL/dv (the direction a
    Large Steps update follows), at K seeds (``CostRule.seeds``, 3):

        d_k     = g~_e(s_k) - g~_base(s_k)              the effect's term, seeds paired
        |E d|^2 ~ mean over k < l of d_k . d_l           unbiased: different seeds' noise is independent
        share_e = sqrt(max(|E d|^2, 0)) / |mean_k g~_e(s_k)|

    and its standard error from the spread of the pair products gives a z-score: a term that does
    not stand out of its own noise (z < ``z_score``) does not pay, whatever its estimate.

    ``share_e`` is the bias a run without the effect keeps in its steps, relative to the step: the
    optimiser settles where its biased gradient vanishes, so the shape stays off by about that
    share of what is left to fit. The cost is the median time of a step with and without the
    effect (kernels compiled by an untimed step first); ``ratio_e = seconds_e / seconds_base``.

    Shadow gradients are charged at most ``shadow_samples.RATIO``: each level cuts their samples
    until a step costs no more (:mod:`backend.optimize.shadow_samples`), and the share is that of
    an unbiased term whatever its sample count.

    Selection: the effect is on when z >= ``z_score`` and ``share_e >= value * (ratio_e - 1)``: the bias it removes
    must be worth the share of steps it costs (``value`` = 0.1: a step 1.3x as long must remove 3 %
    of the gradient; a free effect is on as soon as its term stands out of the noise,
    ``share_e >= min_share``).
    """
    rule = rule or CostRule()
    system = LaplacianSystem(faces, n_vertices, lambda_)

    def timed(config) -> tuple[float, list[np.ndarray]]:
        gradient(config, rule.seeds[0] + 7)  # compiles this configuration's kernels
        grads, times = [], []
        for seed in rule.seeds:
            start = time.perf_counter()
            grads.append(_smoothed(system, gradient(config, seed)))
            times.append(time.perf_counter() - start)
        return float(np.median(times)), grads

    base_seconds, base_grads = timed(base)
    out = {}
    for name, config in candidates.items():
        seconds, grads = timed(config)
        share, noise, z = term_share(grads, base_grads)
        cost = EffectCost(name, seconds, base_seconds, share, noise, z, cap=CAPS.get(name))
        cost.pays = rule.pays(cost)
        out[name] = cost
    return out


def term_share(with_effect: list[np.ndarray], without: list[np.ndarray]) -> tuple[float, float, float]:
    """(share, noise, z) of the paired differences (see ``measure``)."""
    d = [a - b for a, b in zip(with_effect, without)]
    norm = float(np.linalg.norm(np.mean(with_effect, axis=0))) or 1e-30
    products = np.array([float(np.sum(d[k] * d[l])) for k in range(len(d)) for l in range(k + 1, len(d))])
    signal = float(products.mean())
    # the pair products share terms, so their spread understates the error a little: z is a guide
    error = float(products.std(ddof=1) / np.sqrt(len(products))) if len(products) > 1 else abs(signal)
    mean_d = np.mean(d, axis=0)
    noise = float(np.sqrt(np.mean([np.sum((x - mean_d) ** 2) for x in d]))) / norm
    return float(np.sqrt(max(signal, 0.0))) / norm, noise, signal / max(error, 1e-30)
