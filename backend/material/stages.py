"""Material optimisation stages, called by the reconstruction loop between geometry steps.

Each stage takes a SceneRenderer (built with ``material.field``), the target images (linear
RGB, one per renderer view) and per-pixel weights (object masks, 0-1), and updates the
material in place by Adam on the latent parameters through path-traced renders (use an AD
integrator such as ``prb``; its max_depth decides how much global illumination is modelled).

    schedule = MaterialSchedule()                                  # material.schedule
    while schedule.stage != "done":
        ... geometry steps ...
        run_cycle(schedule, renderer, images, weights, material)   # one material cycle
        # after a re-mesh that restarts the material from grey: material.on_remesh(mesh); schedule.on_remesh()

Stages: ``constant`` (one albedo, specular and roughness per material; the first cycles),
``diffuse`` (mesh-color albedo from the constants, specular highlights dropped from the
loss; the first such cycle also fits the environment brightness factor), ``specular``
(mesh-color specular with a variance penalty, roughness per material, albedo refined)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import binary_erosion

from ..lighting.light_factor import ENV_SCALE, LightFactor
from .field import squash
from .model import MeshColorMaterial


@dataclass
class FitSettings:
    iterations: int = 40
    lr: float = 0.1  # Adam step on latents (logits)
    lr_decay: float = 0.1  # the step shrinks exponentially to lr x lr_decay at the last iteration
    light_lr: float = 0.02  # Adam step on the log brightness factor
    spp: int = 0  # 0: the renderer's
    views_per_step: int = 1
    variance_weight: float = 0.0  # lambda in lambda * Var(specular) (per material)
    smoothness_weight: float = 1.0  # x mean squared difference of neighbouring mesh-color samples
    highlight_threshold: float = 0.15  # drop pixels whose predicted highlight exceeds this share
    edge_erosion: int = 1  # pixels dropped inside each mask's outline (see silhouette_weights)
    robust: float = 0.0  # > 0: Charbonnier loss with this scale (linear radiance) instead of squared error
    # every check_every-th view is left out of the specular stage's fits, so that the finished
    # specular texture can be tested on views it was not fitted to (0: none left out)
    check_every: int = 8
    seed: int = 0


@dataclass
class FitResult:
    stage: str
    losses: list[float] = field(default_factory=list)
    light_factor: float = 1.0
    highlight_share: float = 0.0  # share of object pixels dropped as highlights
    seconds: float = 0.0
    reverted: bool = False  # the stage raised the full-view loss, so the material before it was kept

    @property
    def loss(self) -> float:
        tail = self.losses[-max(1, len(self.losses) // 4):]
        return float(np.mean(tail)) if tail else math.nan


def _tensor(a: np.ndarray) -> mi.TensorXf:
    return mi.TensorXf(np.ascontiguousarray(a, dtype=np.float32))


def _weights(weights, images) -> list[np.ndarray]:
    """Per-view (H, W) weights; None (no masks) weighs every pixel."""
    if weights is None:
        return [np.ones(img.shape[:2], np.float32) for img in images]
    return [np.ones(img.shape[:2], np.float32) if w is None else np.asarray(w, np.float32)
            for w, img in zip(weights, images)]


def pixel_loss(diff, robust: float = 0.0):
    """Per-entry loss of a residual: squared, or with ``robust`` > 0 the Charbonnier loss
    2 c (sqrt(d^2 + c^2) - c), squared near 0 and linear beyond c, so the few pixels that
    wrong geometry shades far off weigh less than under squared error (Dr.Jit)."""
    if robust <= 0:
        return dr.square(diff)
    return 2.0 * robust * (dr.sqrt(dr.square(diff) + robust * robust) - robust)


def silhouette_weights(weights: list[np.ndarray], erosion: int) -> list[np.ndarray]:
    """The weights with an ``erosion``-pixel band inside each mask's outline set to zero.

    Along the silhouette a reconstructed surface that is slightly off shows another part of
    the object, or grazes it at the wrong angle, so those pixels pull the material toward
    values that only make up for the geometry (and soft edge pixels mix in the background)."""
    if erosion <= 0:
        return weights
    out = []
    for w in weights:
        w = np.asarray(w, np.float32)
        inside = binary_erosion(w > 0.5, iterations=erosion, border_value=1)
        out.append(w * inside)
    return out


def _weights3(w: np.ndarray) -> np.ndarray:
    w = np.asarray(w, np.float32)
    return np.repeat(w[..., None], 3, -1) if w.ndim == 2 else w


def variance_penalty(material: MeshColorMaterial, name: str):
    """Mean over samples of the squared deviation from their material's mean value (Dr.Jit)."""
    ch = material.channels[name]
    width, lo, hi = material.CHANNELS[name]
    if ch.kind != "colors":
        return mi.Float(0.0)
    v = squash(ch.latent, lo, hi)
    face, _ = material.layout.sample_sites()
    group = np.repeat(material.labels[np.maximum(face, 0)] * width, width) + np.tile(np.arange(width), len(face))
    counts = np.maximum(np.bincount(group, minlength=material.n_materials * width), 1)
    group_dr = mi.UInt32(group.astype(np.uint32))
    sums = dr.zeros(mi.Float, material.n_materials * width)
    dr.scatter_reduce(dr.ReduceOp.Add, sums, v, group_dr)
    mean = dr.gather(mi.Float, sums / mi.Float(counts.astype(np.float32)), group_dr)
    return dr.mean(dr.square(v - mean))


def sample_edges(material: MeshColorMaterial) -> tuple[mi.UInt32, mi.UInt32]:
    """Pairs of neighbouring mesh-color samples (the edges of the sub-triangles)."""
    if material.resolution == 0:
        return mi.UInt32(), mi.UInt32()
    tris = material.layout.sub_triangles()
    edges = np.unique(np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), 1), axis=0)
    return mi.UInt32(edges[:, 0].astype(np.uint32)), mi.UInt32(edges[:, 1].astype(np.uint32))


def smoothness_penalty(material: MeshColorMaterial, name: str, edges: tuple[mi.UInt32, mi.UInt32]):
    """Mean squared difference between neighbouring samples of a mesh-color channel (Dr.Jit)."""
    ch = material.channels[name]
    width, lo, hi = material.CHANNELS[name]
    a, b = edges
    if ch.kind != "colors" or dr.width(a) == 0:
        return mi.Float(0.0)
    kind = mi.Color3f if width == 3 else mi.Float
    diff = squash(dr.gather(kind, ch.latent, a), lo, hi) - squash(dr.gather(kind, ch.latent, b), lo, hi)
    return dr.mean(dr.squared_norm(diff) if width == 3 else dr.square(diff))


def fit(renderer, images: list[np.ndarray], weights: list[np.ndarray] | None, material: MeshColorMaterial,
        names: list[str], settings: FitSettings, light: bool = False, stage: str = "fit",
        emit=None, views: list[int] | None = None, lighting=None) -> FitResult:
    """Adam on the named channels' latents (and the map's log brightness factor when ``light``:
    backend.lighting.light_factor), minimising the weighted mean squared error of renders
    against ``images`` (only the ``views`` among them, when given) plus the variance penalty.
    ``lighting`` (a backend.lighting.base.LightingModel: the estimated map or the flash) adds
    its fit's latent and penalty."""
    start = time.time()
    weights = _weights(weights, images)
    opt = mi.ad.Adam(lr=settings.lr, mask_updates=True)
    params = material.parameters()
    for n in names:
        opt[n] = params[n]
    fits = [LightFactor(material, settings.light_lr)] if light else []  # backend.lighting.base.LightingFit
    fits += [lighting.fit()] if lighting is not None else []
    fits = [f for f in fits if f.present(renderer)]
    for f in fits:
        f.prepare(renderer, images, weights, views)  # a closed-form start where the model has one
        opt[f.NAME] = f.initial()
    targets = [_tensor(img[..., :3]) for img in images]
    w = [_tensor(_weights3(x)) for x in weights]
    norms = [max(float(np.sum(x)), 1e-6) for x in weights]
    rng = np.random.default_rng(settings.seed)
    order: list[int] = []
    result = FitResult(stage)
    pool = list(range(len(images))) if views is None else list(views)
    edges = sample_edges(material) if settings.smoothness_weight else None
    for it in range(settings.iterations):
        decay = settings.lr_decay ** (it / max(settings.iterations - 1, 1))
        opt.set_learning_rate({**{n: settings.lr * decay for n in names}, **{f.NAME: f.lr * decay for f in fits}})
        material.load_parameters({n: opt[n] for n in names})
        loss = 0.0
        count = min(settings.views_per_step, len(pool))
        for _ in range(count):
            if not order:
                order = [pool[i] for i in rng.permutation(len(pool))]
            v = int(order.pop())
            for f in fits:  # per view: the last backward pass used up the graph from the latents
                f.apply(renderer, opt[f.NAME])
            img = renderer.render(v, seed=settings.seed * 100003 + it * 17 + v,
                                  spp=settings.spp or None, params=material.attach(renderer.params))
            view_loss = dr.sum(w[v] * pixel_loss(img - targets[v], settings.robust)).array / (norms[v] * count)
            # one backward pass per view: the integrator re-traces the scene when differentiating,
            # so it must happen while this view's lights are still in place
            dr.backward(view_loss)
            loss += float(view_loss[0])
        penalty = mi.Float(0.0)
        if settings.variance_weight and "specular" in names:
            penalty += settings.variance_weight * variance_penalty(material, "specular")
        if settings.smoothness_weight:
            for n in names:
                penalty += settings.smoothness_weight * smoothness_penalty(material, n, edges)
        for f in fits:
            penalty += f.penalty(opt[f.NAME])
        dr.backward(penalty, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
        opt.step()
        result.losses.append(loss + float(penalty[0]))
        if emit:
            emit("progress", stage=f"material:{stage}", iteration=it + 1, iterations=settings.iterations,
                 loss=result.losses[-1], faces=material.n_faces)
    material.load_parameters({n: dr.detach(opt[n]) for n in names})
    for f in fits:
        f.finish(renderer, opt[f.NAME])
    result.light_factor = material.light_factor
    result.seconds = time.time() - start
    return result


def evaluate_loss(renderer, images, weights, material: MeshColorMaterial, spp: int = 0, seed: int = 7,
                  views: list[int] | None = None) -> float:
    """Weighted mean squared error over all views, or the given ``views`` (no gradients, fixed seeds)."""
    weights = _weights(weights, images)
    views = range(len(images)) if views is None else views
    total = 0.0
    for v in views:
        out = renderer.render_numpy(v, seed=seed + v, spp=spp or None)[..., :3]
        w3 = _weights3(weights[v])
        total += float(np.sum(w3 * (out - images[v][..., :3]) ** 2) / max(np.sum(weights[v]), 1e-6))
    return total / len(views)


def check_views(n_views: int, every: int) -> list[int]:
    """Every ``every``-th view, spread over the capture, when that leaves at least two (else none)."""
    if every <= 0 or n_views < 2 * every:
        return []
    return list(range(every // 2, n_views, every))


def check_specular_texture(renderer, images, weights, material: MeshColorMaterial, views: list[int],
                           spp: int = 0) -> dict:
    """Keep mesh-color specular only if it renders ``views`` (views the specular stage was not
    fitted to) better than its per-material mean; otherwise specular becomes that constant.

    On the views it was fitted to, a specular texture always wins: it also absorbs what the
    surface still gets wrong (a misplaced highlight dimmed, a missing one painted in), which
    other views do not repeat."""
    textured = evaluate_loss(renderer, images, weights, material, spp, views=views)
    texture = material.values("specular").copy()
    material.make_constant("specular")
    constant = evaluate_loss(renderer, images, weights, material, spp, views=views)
    kept = "constant" if constant <= textured else "colors"
    if kept == "colors":
        material.set_values("specular", texture, "colors")
    return {"views": list(views), "colors": textured, "constant": constant, "kept": kept}


class SpecularOnlyField:
    """A material field with the albedo removed (only the specular lobe renders), optionally
    with one fixed roughness."""

    def __init__(self, field, roughness: float | None = None):
        self.inner = field
        self.roughness = roughness

    def arrays(self) -> dict:
        return self.inner.arrays()

    def lookup(self, si, active):
        _, spec, rough = self.inner.lookup(si, active)
        return mi.Color3f(0.0), spec, rough if self.roughness is None else mi.Float(self.roughness)


def highlight_masks(renderer, images, weights, material: MeshColorMaterial, threshold: float = 0.15,
                    spp: int = 0, mirror_roughness: float | None = None) -> list[np.ndarray]:
    """Pixels where the predicted specular highlight is a large share of the observed radiance.

    The geometry is rendered as a mirror under the capture's lights: the specular lobe alone,
    with the material's current specular and roughness (a perfect mirror reflects nothing of a
    point light, so by default the lobe keeps the fitted roughness; ``mirror_roughness`` = 0
    gives the near-perfect mirror). Pixels where it exceeds ``threshold`` x the target are masked."""
    weights = _weights(weights, images)
    old = renderer.field
    renderer.set_field(SpecularOnlyField(material.field, mirror_roughness))
    try:
        out = []
        for v, (img, w) in enumerate(zip(images, weights)):
            h = renderer.render_numpy(v, seed=1000 + v, spp=spp or None)[..., :3]
            lum_h, lum_t = h.mean(-1), np.asarray(img)[..., :3].mean(-1)
            out.append((lum_h > threshold * np.maximum(lum_t, 1e-4)) & (np.asarray(w) > 0))
        return out
    finally:
        renderer.set_field(old)


def fit_constants(renderer, images, weights, material: MeshColorMaterial, settings: FitSettings | None = None,
                  emit=None, names: tuple[str, ...] | None = None, stage: str = "constant",
                  lighting=None) -> FitResult:
    """Stage 1: one albedo, specular and roughness per material (or only the ``names`` channels,
    the others held)."""
    settings = settings or FitSettings()
    names = tuple(material.CHANNELS) if names is None else names
    for name in names:
        material.make_constant(name)
    weights = silhouette_weights(_weights(weights, images), settings.edge_erosion)
    return fit(renderer, images, weights, material, list(names), settings, stage=stage, emit=emit, lighting=lighting)


def fit_lobe(renderer, images, weights, material: MeshColorMaterial, settings: FitSettings | None = None,
             emit=None) -> FitResult:
    """The specular lobe's constants with the albedo held: the constant stage for a lobe turned
    on after the albedo was fitted without it."""
    return fit_constants(renderer, images, weights, material, settings, emit, ("specular", "roughness"), "lobe")


def fit_diffuse(renderer, images, weights, material: MeshColorMaterial, settings: FitSettings | None = None,
                light: bool = False, emit=None, lighting=None) -> FitResult:
    """Stage 2: mesh-color albedo (initialised from the constants), highlights masked out;
    ``light`` also fits the environment brightness factor (the first texture round)."""
    settings = settings or FitSettings()
    weights = silhouette_weights(_weights(weights, images), settings.edge_erosion)
    material.make_spatial("albedo")
    masks = highlight_masks(renderer, images, weights, material, settings.highlight_threshold, settings.spp)
    kept = [np.asarray(w, np.float32) * (~m) for w, m in zip(weights, masks)]
    obj = sum(float((np.asarray(w) > 0).sum()) for w in weights)
    result = fit(renderer, images, kept, material, ["albedo"], settings, light=light, stage="diffuse", emit=emit,
                 lighting=lighting)
    result.highlight_share = sum(float(m.sum()) for m in masks) / max(obj, 1.0)
    return result


def fit_specular(renderer, images, weights, material: MeshColorMaterial, settings: FitSettings | None = None,
                 spatial_roughness: bool = False, emit=None, views: list[int] | None = None,
                 lighting=None) -> FitResult:
    """Stage 3: mesh-color specular with the variance penalty; roughness per material (or mesh
    colors with ``spatial_roughness``); albedo refined, highlights included; fitted to the
    ``views`` only, when given."""
    settings = settings or FitSettings(variance_weight=0.1)
    material.make_spatial("albedo")
    material.make_spatial("specular")
    if spatial_roughness:
        material.make_spatial("roughness")
    weights = silhouette_weights(_weights(weights, images), settings.edge_erosion)
    return fit(renderer, images, weights, material, ["albedo", "specular", "roughness"], settings,
               stage="specular", emit=emit, views=views, lighting=lighting)
