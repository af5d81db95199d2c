"""Per-frame camera response: an exposure x white-balance gain per frame and channel, solved
in closed form between material stages (``--exposure``).

Model. A phone exposes and white-balances every frame on its own, so frame i records
g_i x (the scene's radiance), g_i in R^3 (one gain per colour channel). The gains are
log-parameterised, g_i = exp(a_i), and the loss compares g_i x render_i with frame i. The fit
divides the frame by the gain instead (``Exposure.correct``: T_i / g_i against render_i): the
same model, the residual of frame i weighed by 1 / g_i, and every loss of the run (geometry
steps, material stages, validation) takes it without a change of its own.

Solve. After every material cycle the frames are rendered with the current mesh, material and
light, and per frame and channel

    l_i = log( sum_p w T_i / sum_p w R_i )           (w: the mask, its outline band left out)

is the exact gain of a multiplicative model (T_i = g_i R_i gives l_i = log g_i); a ratio of
sums, not the least-squares ratio sum w R T / sum w R^2, whose denominator the render's noise
biases upwards (E R^2 > (E R)^2) and which the brightest pixels (highlights) dominate. With a
Gaussian prior a_i ~ N(m, tau^2) about the frames' median m = median_i l_i, the MAP gain of a
frame whose log-ratio is known to sigma^2 is

    a_i = (l_i + lambda m) / (1 + lambda),           lambda = sigma^2 / tau^2 (``PRIOR``)

then clamped to [-``LIMIT``, ``LIMIT``]. A closed form rather than one more latent of the
material stages' Adam (as ``LightFactor``): a stage renders one view an iteration, so a
frame's own gain would get one Adam step in N iterations; the solve costs one small render of
every frame (at ``SOLVE_SIZE`` px: a gain is a mean over thousands of pixels).

Gauge. Gains times c and albedo x light over c render the same frames, so the gains carry a
free scale per channel. The convention (``CONVENTION``): the mean log-gain over the frames
is zero per channel (their geometric mean is 1), so albedo and lighting keep the absolute
scale and colour, set by the albedo convention (backend.lighting.convention) or the captured
lights; Cycles previews and result.glb are in those units (the gains are not baked in)."""

from __future__ import annotations

import numpy as np

MODES = ("auto", "off", "per-frame")
HELP = ("per-frame exposure and white balance (three gains a frame, solved between material stages): "
        "'auto' (the default) fits them for captures made from a video or photos (capture-from-video: a "
        "phone exposes every frame on its own) and for those whose capture.json marks the frames as "
        "auto-exposed (synth --exposure-drift), not for imported datasets or other rendered captures; "
        "'per-frame' always; 'off' never")
# capture.json provenance.source of the captures ``auto`` fits gains for: capture-from-video's
AUTO_SOURCES = ("video", "images")
AUTO_FLAG = "auto_exposure"  # capture.json provenance flag: frames exposed one by one (synth --exposure-drift)
PRIOR = 0.05  # lambda = sigma^2 / tau^2: how strongly a frame's gain is pulled to the median
LIMIT = float(np.log(4.0))  # |a| at most: gains within [1/4, 4]
SOLVE_SIZE = 96  # long side of the renders a solve compares (px)
SOLVE_SPP = 16
MIN_PIXELS = 16  # a frame with fewer weighted pixels keeps the median gain
CONVENTION = "mean log-gain over frames = 0 per channel (geometric mean of the gains 1): albedo and lighting carry the absolute scale"


def enabled(mode: str, capture) -> bool:
    """Whether ``--exposure mode`` fits gains for ``capture``: ``auto`` by what capture.json
    says of its source, on for a phone's video or photos (``AUTO_SOURCES``) and for frames its
    provenance marks as auto-exposed (``AUTO_FLAG``: a synthetic phone capture). Rendered captures
    share one exposure, and a fit costs them a little albedo accuracy; imported datasets are
    shot with fixed settings in the main (DTU's per-view brightness follows the camera's
    direction, light that a rig map does not carry, not the exposure: fitted gains took it up
    and the held-out views lost 2.6 dB, docs/notes/2026-12-02-exposure.md)."""
    if mode not in MODES:
        raise ValueError(f"unknown exposure mode {mode!r}")
    if mode != "auto":
        return mode == "per-frame"
    provenance = capture.provenance or {}
    return provenance.get("source") in AUTO_SOURCES or provenance.get(AUTO_FLAG) is True


class Exposure:
    """The gains of ``names`` frames (in capture order), all 1 until the first ``solve``.

    Attributes:
        latent: a = log g, (N, 3) float64.
        solves: how many solves set it.
    """

    def __init__(self, names: list[str], prior: float = PRIOR):
        self.names = list(names)
        self.prior = prior
        self.latent = np.zeros((len(self.names), 3))
        self.solves = 0

    @property
    def gains(self) -> np.ndarray:
        return np.exp(self.latent)

    def correct(self, index: int, target: np.ndarray) -> np.ndarray:
        """Frame ``index`` in the scene's units: T / g (what a render should match)."""
        if self.solves == 0:
            return target
        return (np.asarray(target, np.float32) / self.gains[index].astype(np.float32)).astype(np.float32)

    def solve(self, renders, targets, weights) -> np.ndarray:
        """The MAP gains (see the module) from ``renders`` of every frame (linear RGB, (H, W, 3)),
        the frames as recorded (``targets``, same size) and per-pixel ``weights`` (H, W); sets
        ``latent`` under the gauge and returns the gains."""
        ratios, ok = np.zeros((len(renders), 3)), np.zeros(len(renders), bool)
        for i, (r, t, w) in enumerate(zip(renders, targets, weights)):
            w = np.asarray(w, np.float64)[..., None]
            num = (w * np.asarray(t, np.float64)[..., :3]).sum((0, 1))
            den = (w * np.asarray(r, np.float64)[..., :3]).sum((0, 1))
            if float(w.sum()) >= MIN_PIXELS and np.all(num > 0) and np.all(den > 0):
                ratios[i], ok[i] = np.log(num / den), True
        if not ok.any():
            return self.gains
        median = np.median(ratios[ok], axis=0)
        a = np.where(ok[:, None], (ratios + self.prior * median) / (1.0 + self.prior), median)
        a = np.clip(a - median, -LIMIT, LIMIT)
        self.latent = a - a.mean(axis=0)
        self.solves += 1
        return self.gains

    def state(self) -> dict:
        return {"latent": self.latent.round(8).tolist(), "solves": self.solves}

    def restore(self, state: dict | None) -> None:
        if state:
            self.latent = np.asarray(state["latent"], np.float64).reshape(len(self.names), 3)
            self.solves = int(state["solves"])

    def report(self) -> dict:
        """report.json ``exposure``: the gains per frame, their spread and the convention."""
        g = self.gains
        return {"model": "per-frame", "convention": CONVENTION, "prior": self.prior, "solves": self.solves,
                "gains": {n: [round(float(x), 5) for x in row] for n, row in zip(self.names, g)},
                "range": [[round(float(x), 5) for x in g.min(0)], [round(float(x), 5) for x in g.max(0)]]}


def scoring_gains(fitted: dict | None, names: list[str]) -> dict[str, np.ndarray]:
    """The gain each of ``names``' renders is scored at, from report.json ``exposure``
    (``fitted``): a frame the run fitted, its own gains (the model: frame = g x render); any
    other frame (held out, its exposure never seen) the fitted gains' median per channel, the
    prior's centre; 1 for every frame when the run fitted none."""
    gains = (fitted or {}).get("gains") or {}
    if not gains:
        return {n: np.ones(3, np.float32) for n in names}
    median = np.median(np.array(list(gains.values()), np.float64), axis=0)
    return {n: np.asarray(gains.get(n, median), np.float32) for n in names}


def scoring_note(fitted: dict | None) -> str:
    """How :func:`scoring_gains` scored a run's views (a report's words)."""
    if not (fitted or {}).get("gains"):
        return "gain 1 (one exposure fitted for all frames)"
    return "fitted frames at their fitted gains, other frames at the fitted gains' median"
