"""Simulate only the light-transport effects a scene calls for.

Each effect is *measured* on a few views of the current estimate and kept only when its
contribution in the masked object region stands out from Monte Carlo noise and exceeds a
relative threshold:

- **bounces**: renders at path depth 2, 3, ... with the same seed differ exactly by the
  added bounce (the sample streams agree up to the cut), so each increment is measured with
  little noise; its standard error comes from a second seed. Depth grows while the next
  bounce adds more than ``tolerance`` of the direct image.
- **shadow / indirect-visibility gradients** (``sppi``): the share of direct light that the
  object blocks from itself, by shadow rays from the visible surface toward sampled emitters.
  Only for environment (non-delta) lighting: the projective integrators sample no shadow
  boundaries of point lights, so under point lights alone the term is zero at direct light.
- **accuracy per second** (environment light, with ``probe``): shadow gradients and one more
  bounce are each timed in geometry steps and their share of the step's smoothed gradient is
  measured against the decision without them (:mod:`backend.optimize.effect_costs`); each is
  on when the bias it removes is worth the share of steps it costs. Point-lit captures keep the
  need tests above (the presets' calibration assumes them).
- **specular lobe**: how much brighter the targets are, relative to diffuse shading, where a
  unit-specular render says highlights would be than in the pixels just around them.
- **silhouette gradients**: projective integrators only while geometry is optimised.
- **emitters**: only the emitter types the capture has (point lights, environment map).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from .fields import ConstantField
from .scene import RenderSettings

EFFECTS = ("indirect", "shadows", "specular", "silhouettes")
# indirect-visibility samples per pixel with shadow gradients (unguided, RenderSettings.guiding):
# about as accurate as Mitsuba's octree-guided 4 and within 2x of a step without them
# (docs/notes/2026-11-24-hdr-shadow-gradients.md)
SHADOW_SPPI = 12


@dataclass
class EffectsConfig:
    tolerance: float = 0.01  # relative contribution below which an effect is dropped
    z_score: float = 3.0  # significance against Monte Carlo noise
    max_depth_probe: int = 6
    # self-shadowing share (environment light) above which shadow gradients are needed when no
    # cost probe weighs them: the term is about as large, relative to the gradient, as the share
    shadow_threshold: float = 0.05
    # targets over diffuse fit, in highlight regions: a wrong diffuse-only decision costs accuracy
    # and saves no time, so the bar is just above what diffuse objects measure (docs/method.md)
    highlight_ratio: float = 1.03
    views: int = 4
    spp: int = 16


@dataclass
class EffectsDecision:
    max_depth: int = 2
    shadows: bool = False
    specular: bool = True
    silhouettes: bool = True
    emitters: list[str] = field(default_factory=list)
    measured: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    forced: dict = field(default_factory=dict)

    def settings(self, base: RenderSettings, geometry: bool, sppi: int = SHADOW_SPPI) -> RenderSettings:
        """Render settings for a stage: projective only when geometry moves, sppi only with shadows."""
        projective = geometry and self.silhouettes
        if self.max_depth <= 2:
            integrator = "direct_projective" if projective else "prb"
        else:
            integrator = "prb_projective" if projective else "prb"
        return RenderSettings(spp=base.spp, max_depth=self.max_depth, integrator=integrator,
                              hide_emitters=base.hide_emitters, sppc=base.sppc, sppp=base.sppp,
                              sppi=sppi if (projective and self.shadows) else 0, guiding=base.guiding,
                              rr_depth=base.rr_depth, primal_spp=base.primal_spp if projective else 0)

    def to_json(self) -> dict:
        return asdict(self)


def parse_effects(spec: str) -> tuple[bool, dict[str, bool]]:
    """'auto' | 'all' | a comma list like 'indirect,specular' or 'auto,-shadows'.

    Returns (measure, overrides): whether to measure at all, and effects forced on/off."""
    items = [s.strip() for s in spec.split(",") if s.strip()]
    measure = "auto" in items or not items
    overrides: dict[str, bool] = {}
    if "all" in items:
        overrides = {e: True for e in EFFECTS}
    listed = [s for s in items if s not in ("auto", "all")]
    for item in listed:
        name, on = (item[1:], item[0] != "-") if item[0] in "+-" else (item, True)
        if name not in EFFECTS:
            raise ValueError(f"unknown effect '{name}' (known: {', '.join(EFFECTS)}, auto, all)")
        overrides[name] = on
    if listed and not measure and "all" not in items:
        # an explicit list: unlisted light-transport effects are off; silhouette gradients are
        # not light transport and stay on unless named with '-'
        overrides = {e: overrides.get(e, e == "silhouettes") for e in EFFECTS}
    return measure, overrides


def _masked(img: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return img[..., :3][mask > 0.5]


def _integrator(depth: int) -> mi.Integrator:
    return mi.load_dict({"type": "path", "max_depth": depth, "hide_emitters": True})


def measure_bounces(renderer, views, masks, cfg: EffectsConfig) -> dict:
    """Relative contribution (and z-score) of each added bounce, per depth."""
    increments = {d: [] for d in range(3, cfg.max_depth_probe + 1)}
    direct_sum = 0.0
    for view, mask in zip(views, masks):
        if not np.any(mask > 0.5):  # the object is not in this view: nothing to measure
            continue
        renderer._set_lights(view)
        by_seed = []
        for seed in (11, 12):
            imgs = {d: _masked(np.array(mi.render(renderer.scene, sensor=renderer.sensors[view],
                                                  integrator=_integrator(d), spp=cfg.spp, seed=seed)), mask)
                    for d in range(2, cfg.max_depth_probe + 1)}
            by_seed.append(imgs)
        direct_sum += float(np.mean([s[2].sum() for s in by_seed]))
        for d in increments:
            a = by_seed[0][d] - by_seed[0][d - 1]
            b = by_seed[1][d] - by_seed[1][d - 1]
            increments[d].append((a.sum() + b.sum()) / 2)
            increments[d].append(np.abs(a - b).std() * np.sqrt(a.size) / 2)  # std error of the sum
    out = {}
    for d, vals in increments.items():
        total, err = sum(vals[0::2]), np.sqrt(sum(v * v for v in vals[1::2]))
        out[d] = {"relative": float(total / max(direct_sum, 1e-12)), "z": float(abs(total) / max(err, 1e-12))}
    return out


def measure_self_shadowing(renderer, views, masks, samples: int = 4) -> float:
    """Share of unoccluded direct light (cosine-weighted) that the scene blocks at visible points."""
    blocked = total = 0.0
    for view, mask in zip(views, masks):
        renderer._set_lights(view)
        sensor = renderer.sensors[view]
        h, w = mask.shape
        ys, xs = np.nonzero(mask > 0.5)
        if len(xs) == 0:
            continue
        uv = mi.Point2f(((xs + 0.5) / w).astype(np.float32), ((ys + 0.5) / h).astype(np.float32))
        ray, _ = sensor.sample_ray(0.0, 0.5, uv, mi.Point2f(0.5, 0.5))
        si = renderer.scene.ray_intersect(ray)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(7, len(xs))
        for _ in range(samples):
            ds, weight = renderer.scene.sample_emitter_direction(si, sampler.next_2d(), False, si.is_valid())
            cos = dr.maximum(dr.dot(si.n, ds.d), 0.0)
            contribution = np.array(mi.luminance(weight) * cos)
            occluded = np.array(renderer.scene.ray_test(si.spawn_ray_to(ds.p), si.is_valid() & (cos > 0)))
            contribution = np.where(np.array(si.is_valid()), contribution, 0.0)
            total += float(contribution.sum())
            blocked += float(contribution[occluded].sum())
            sampler.advance()
    return blocked / max(total, 1e-12)


def measure_highlights(renderer, views, targets, masks, cfg: EffectsConfig, top: float = 0.05,
                       ring: int = 3) -> float:
    """Target / diffuse-fit ratio in the pixels a unit-specular render lights most, against the
    same ratio in a ring of neighbouring pixels (mostly the same material, so texture cancels)."""
    from scipy.ndimage import binary_dilation

    saved = renderer.field
    try:
        renderer.set_field(ConstantField([1.0, 1.0, 1.0], 0.0, 1.0))
        diffuse = [renderer.render_numpy(v, seed=3, spp=cfg.spp) for v in views]
        renderer.set_field(ConstantField([0.0, 0.0, 0.0], 1.0, 0.3))
        spec = [renderer.render_numpy(v, seed=3, spp=cfg.spp) for v in views]
    finally:
        renderer.set_field(saved)
    hi_sum = hi_pred = ring_sum = ring_pred = 0.0
    for e, s, t, m in zip(diffuse, spec, targets, masks):
        inside = (m > 0.5) & (e[..., :3].mean(-1) > 1e-4)
        if inside.sum() < 20:
            continue
        el, sl, tl = e[..., :3].mean(-1), s[..., :3].mean(-1), t[..., :3].mean(-1)
        hi = inside & (sl >= np.quantile(sl[inside], 1 - top)) & (sl > 0)
        around = binary_dilation(hi, iterations=ring) & inside & ~hi
        hi_sum, hi_pred = hi_sum + tl[hi].sum(), hi_pred + el[hi].sum()
        ring_sum, ring_pred = ring_sum + tl[around].sum(), ring_pred + el[around].sum()
    if hi_pred <= 0 or ring_pred <= 0 or ring_sum <= 0:
        return 1.0
    return float((hi_sum / hi_pred) / (ring_sum / ring_pred))


def weigh_costs(decision: EffectsDecision, probe, cfg: EffectsConfig, overrides: dict[str, bool]) -> None:
    """Shadow gradients and one more bounce, each kept when it pays per second of step.

    ``probe(base, candidates)`` -> {name: cost} times geometry steps of the ``base`` decision
    and of each candidate decision and measures the candidate's share of the gradient; a cost
    has ``pays`` and ``to_json()`` (:class:`backend.optimize.effect_costs.EffectCost`)."""
    base = decision if "shadows" in overrides else replace(decision, shadows=False)
    candidates = {}
    if "shadows" not in overrides:
        candidates["shadows"] = replace(base, shadows=True)
    if "indirect" not in overrides and base.max_depth < cfg.max_depth_probe:
        candidates["bounce"] = replace(base, max_depth=base.max_depth + 1)
    if not candidates:
        return
    costs = probe(base, candidates)
    decision.measured["costs"] = {name: cost.to_json() for name, cost in costs.items()}
    for name, cost in costs.items():
        verdict = "pays" if cost.pays else "does not pay"
        held = f", held to {cost.charged:.2f}x" if cost.charged < cost.ratio else ""
        why = (f"{verdict}: {100 * cost.share:.1f}% of the gradient (z {cost.z:.1f}) "
               f"for {cost.ratio:.2f}x the step time{held}")
        if name == "shadows":
            decision.shadows = cost.pays
            decision.reasons["shadows"] += f"; {why}"
        else:
            decision.max_depth += int(cost.pays)
            decision.reasons["indirect"] += f"; bounce {base.max_depth + 1} {why}"


def decide(renderer, targets, masks, emitters: list[str], cfg: EffectsConfig | None = None,
           overrides: dict[str, bool] | None = None, measure: bool = True, probe=None) -> EffectsDecision:
    """Measure on a few views and decide which effects to simulate (``probe``: see
    :func:`weigh_costs`; used under environment light)."""
    cfg = cfg or EffectsConfig()
    overrides = overrides or {}
    decision = EffectsDecision(emitters=emitters, forced=dict(overrides))
    n = len(targets)
    views = sorted(set(np.linspace(0, n - 1, min(cfg.views, n)).round().astype(int).tolist()))
    v_targets, v_masks = [targets[v] for v in views], [masks[v] for v in views]
    if measure:
        seconds, clock = {}, time.perf_counter()

        def lap(name):
            nonlocal clock
            seconds[name], clock = round(time.perf_counter() - clock, 3), time.perf_counter()

        with dr.suspend_grad():
            bounces = measure_bounces(renderer, views, v_masks, cfg)
            lap("bounces")
            point_only = bool(emitters) and all(e == "point" for e in emitters)
            shadow = None if point_only else measure_self_shadowing(renderer, views, v_masks)
            lap("self_shadowing")
            ratio = measure_highlights(renderer, views, v_targets, v_masks, cfg)
            lap("highlights")
        depth = 2
        for d in sorted(bounces):
            b = bounces[d]
            if b["relative"] > cfg.tolerance and b["z"] > cfg.z_score:
                depth = d
            else:
                break
        decision.max_depth = depth
        decision.shadows = shadow is not None and shadow > cfg.shadow_threshold
        decision.specular = ratio > cfg.highlight_ratio
        decision.measured = {"bounces": {str(k): v for k, v in bounces.items()}, "self_shadowing": shadow,
                             "highlight_ratio": ratio, "views": views, "seconds": seconds}
        decision.reasons = {
            "indirect": (f"bounce {depth + 1} adds {100 * bounces.get(depth + 1, {'relative': 0})['relative']:.2f}%"
                         f" (< {100 * cfg.tolerance:g}% or not significant)" if depth < cfg.max_depth_probe
                         else "still significant at the probe depth"),
            "shadows": ("point lights only: no shadow-boundary samples for delta lights" if shadow is None else
                        f"self-shadowing {100 * shadow:.1f}% vs threshold {100 * cfg.shadow_threshold:g}%"),
            "specular": f"highlight ratio {ratio:.2f} vs threshold {cfg.highlight_ratio}",
        }
        if probe is not None and shadow is not None:
            weigh_costs(decision, probe, cfg, overrides)
            lap("costs")
    else:
        decision.max_depth, decision.shadows, decision.specular = cfg.max_depth_probe, True, True
    if "indirect" in overrides:
        decision.max_depth = max(decision.max_depth, 4) if overrides["indirect"] else 2
    if "shadows" in overrides:
        decision.shadows = overrides["shadows"]
    if "specular" in overrides:
        decision.specular = overrides["specular"]
    if "silhouettes" in overrides:
        decision.silhouettes = overrides["silhouettes"]
    return decision
