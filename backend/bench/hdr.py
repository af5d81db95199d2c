"""HDR-lit step cost: forward, backward and guiding time of shadow-gradient configurations, and their gradients' agreement with a reference.

A shared mesh (armadillo or Bob, simplified to ``--faces``) under a shared Poly Haven HDR
map is the truth; the estimate is the truth displaced along its normals by a smooth field
(``--offset`` of the bounding radius), so the geometry gradient is far from zero. Every
configuration runs ``--steps`` geometry steps as the optimiser does (``--views-per-step``
views, one ``mi.render`` and one backward pass each, the integrator's own sample counts) and
is timed per step: forward (primal render and loss), backward (everything in the backward
pass) and, within backward, the construction of the indirect-silhouette guiding structure.

Agreement is measured on the vertex-position gradient of the step's views against a
reference: the silhouette-free and primary-silhouette part at ``--ref-spp`` plus the
indirect (shadow) part at ``--ref-sppi``, averaged over ``--ref-rounds`` fresh octree
builds, both backpropagated from a ``--ref-spp`` primal render. Columns: cosine similarity
and norm ratio of the step's full gradient, and the agreement of its indirect part alone,
computed again with the step's seed and guiding structure but the reference's adjoint (so
the primal render's noise, shared by every configuration, stays out of the comparison).

A configuration is a comma list of integrator properties, ``;`` between configurations:
``sppi``, ``guiding`` (none/grid/octree; Mitsuba's octree when not given), ``guiding_rounds``, ``guiding_reuse`` (steps a
per-view structure is reused; the bench measures it built ``reuse - 1`` steps of
``--step-move`` earlier, the oldest it gets), ``guiding_seed_spp``, ``guiding_leaf_samples``,
``every`` (shadow terms only on every k-th step; the other steps run without them)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import variant
from ..capture.images import read_rgba
from ..capture.model import Environment
from ..geometry.mesh import Mesh, load_mesh
from ..geometry.simplify import simplify
from ..material.constant import ConstantMaterial
from ..optimize.objective import Objective
from ..optimize.steps import LaplacianSystem, clip_outliers
from ..optimize.views import View
from ..render import effects, projective  # noqa: F401  (registers the sft_ integrators)
from ..render.fields import ConstantField
from ..render.scene import RenderSettings, SceneRenderer
from ..synth import layout
from . import _records

SHARED = Path(os.environ.get("SFT_SHARED_DATA", "/work/shared/data"))
MESHES = {"armadillo": "meshes/stanford/armadillo_86k.obj", "bob": "meshes/crane/bob/bob_tri.obj"}
ENVMAPS = {"studio": "envmaps/studio_small_03_1k.hdr", "sunset": "envmaps/venice_sunset_1k.hdr",
           "forest": "envmaps/forest_slope_1k.hdr"}
DEFAULT_CONFIGS = ("sppi=0;sppi=4;sppi=4,guiding=grid;sppi=4,guiding=none;sppi=4,guiding_seed_spp=64,"
                   "guiding_leaf_samples=32;sppi=4,guiding_reuse=4;sppi=4,every=4")
INTEGER_KEYS = ("sppi", "guiding_rounds", "guiding_reuse", "guiding_seed_spp", "guiding_leaf_samples", "every")


def parse_config(spec: str) -> dict:
    """'sppi=4,guiding=grid' -> {'sppi': 4, 'guiding': 'grid'}."""
    out: dict = {}
    for item in [s.strip() for s in spec.split(",") if s.strip()]:
        key, _, value = item.partition("=")
        if key not in INTEGER_KEYS + ("guiding", "guiding_move"):
            raise ValueError(f"unknown configuration key '{key}'")
        out[key] = int(value) if key in INTEGER_KEYS else (float(value) if key == "guiding_move" else value)
    return out


def agreement(g: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(cosine similarity, |g| / |ref|) of two gradients."""
    a, b = g.ravel(), ref.ravel()
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    return (float(a @ b) / max(na * nb, 1e-30), na / max(nb, 1e-30))


def smooth_field(points: np.ndarray, seed: int, waves: int = 6) -> np.ndarray:
    """A smooth scalar field in [-1, 1] over ``points`` (a sum of random plane waves)."""
    rng = np.random.default_rng(seed)
    radius = float(np.linalg.norm(points - points.mean(0), axis=1).max())
    out = np.zeros(len(points))
    for _ in range(waves):
        k = rng.normal(size=3)
        k *= rng.uniform(1.0, 3.0) / (np.linalg.norm(k) * radius)
        out += np.sin(2 * np.pi * points @ k + rng.uniform(0, 2 * np.pi))
    return out / max(np.abs(out).max(), 1e-12)


def build_scene(args):
    """(truth mesh, estimate mesh, cameras, environment, env pixels, per-step displacement)."""
    mesh = load_mesh(SHARED / MESHES[args.mesh])
    v = mesh.vertices @ np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # Y up -> Z up
    lo, hi = v.min(0), v.max(0)
    v = (v - (lo + hi) / 2) / (np.linalg.norm(hi - lo) / 2)
    truth = simplify(Mesh(v, mesh.faces), args.faces)
    truth = Mesh(truth.vertices, truth.faces)
    normals = truth.vertex_normals()
    estimate = Mesh(truth.vertices + args.offset * smooth_field(truth.vertices, 1)[:, None] * normals, truth.faces)
    f = truth.faces
    edge = float(np.linalg.norm(truth.vertices[f] - truth.vertices[np.roll(f, 1, 1)], axis=-1).mean())
    direction = smooth_field(truth.vertices, 2)[:, None] * normals
    step = args.step_move * edge * direction / np.abs(direction).max()
    cams = layout.orbit_cameras(layout.fibonacci_sphere(args.views), np.zeros(3), 1.0, args.resolution)
    env = Environment(SHARED / ENVMAPS[args.envmap], args.strength, args.rotation)
    pixels = read_rgba(env.path)[0][..., :3]
    return truth, estimate, cams, env, pixels, step, edge


def add_scene_arguments(parser) -> None:
    """The scene and the optimiser's step: what ``bench hdr`` and ``bench steps`` share."""
    parser.add_argument("--mesh", choices=sorted(MESHES), default="armadillo", help="default: %(default)s")
    parser.add_argument("--envmap", choices=sorted(ENVMAPS), default="sunset", help="default: %(default)s")
    parser.add_argument("--strength", type=float, default=1.0, help="environment strength (default: %(default)s)")
    parser.add_argument("--rotation", type=float, default=0.0, help="environment rotation about Z, degrees")
    parser.add_argument("--faces", type=int, default=5000, help="default: %(default)s")
    parser.add_argument("--resolution", type=int, default=64, help="image size in pixels (default: %(default)s)")
    parser.add_argument("--views", type=int, default=8, help="cameras on a sphere (default: %(default)s)")
    parser.add_argument("--views-per-step", type=int, default=2, help="default: %(default)s")
    parser.add_argument("--max-depth", type=int, default=2,
                        help="path vertices; 2 = direct light (direct_projective), more: prb_projective "
                             "(default: %(default)s)")
    parser.add_argument("--spp", type=int, default=16, help="sppc of a step (default: %(default)s)")
    parser.add_argument("--sppp", type=int, default=4, help="primary-silhouette spp of a step (default: %(default)s)")
    parser.add_argument("--offset", type=float, default=0.02,
                        help="estimate's displacement from the truth, in bounding radii (default: %(default)s)")
    parser.add_argument("--step-move", type=float, default=0.1,
                        help="largest vertex move per step, in mean edge lengths (the optimiser's step cap; "
                             "default: %(default)s)")
    parser.add_argument("--smoothing", type=float, default=2.0,
                        help="Large Steps lambda of the optimiser's direction (default: %(default)s, the soft system)")
    parser.add_argument("--clip", type=float, default=95.0,
                        help="per-vertex gradient cap percentile of the optimiser's direction (default: %(default)s)")


def add_arguments(parser) -> None:
    add_scene_arguments(parser)
    parser.add_argument("--steps", type=int, default=3, help="timed steps per configuration (default: %(default)s)")
    parser.add_argument("--ref-spp", type=int, default=256, help="default: %(default)s")
    parser.add_argument("--ref-sppi", type=int, default=64, help="default: %(default)s")
    parser.add_argument("--ref-rounds", type=int, default=3,
                        help="fresh octree builds averaged for the indirect reference (default: %(default)s)")
    parser.add_argument("--configs", default=DEFAULT_CONFIGS, help="';'-separated (default: %(default)s)")
    parser.add_argument("--out", type=Path, help="write the results as JSON here")


class _Bench:
    def __init__(self, args):
        self.args = args
        truth, self.estimate, cams, self.env, self.pixels, self.step_move, self.edge = build_scene(args)
        self.truth_faces = truth.n_faces
        n = len(cams)
        albedo = [0.6, 0.6, 0.6]
        truth_r = SceneRenderer(truth, ConstantField(albedo, 0.0, 0.5), cams, [[]] * n, self.env,
                                RenderSettings(spp=args.ref_spp, max_depth=args.max_depth), env_pixels=self.pixels,
                                rgba=True)
        rgba = [truth_r.render_numpy(i, seed=i) for i in range(n)]
        masks = [r[..., 3] for r in rgba]
        with dr.suspend_grad():
            self.self_shadowing = effects.measure_self_shadowing(truth_r, list(range(n)), masks)
        self.views = [View(f"{i:02d}", c, r[..., :3] * r[..., 3:], r[..., 3], []) for i, (c, r) in
                      enumerate(zip(cams, rgba))]
        self.material = ConstantMaterial(albedo, 0.0, 0.5, estimate=False)
        self.Objective, self.RenderSettings = Objective, RenderSettings
        self.integrator = "sft_direct_projective" if args.max_depth <= 2 else "sft_prb_projective"

    # -- objectives --------------------------------------------------------------------------
    def objective(self, config: dict, sppc: int | None = None, sppp: int | None = None):
        a = self.args
        settings = self.RenderSettings(spp=a.spp, max_depth=a.max_depth,
                                       integrator="direct_projective" if a.max_depth <= 2 else "prb_projective",
                                       sppc=a.spp if sppc is None else sppc, sppp=a.sppp if sppp is None else sppp,
                                       sppi=config.get("sppi", 0))
        obj = self.Objective(self.estimate, self.material, self.views, settings, self.env, self.pixels)
        props = {k: v for k, v in config.items() if k in ("guiding", "guiding_rounds", "guiding_reuse",
                                                          "guiding_seed_spp", "guiding_leaf_samples",
                                                          "guiding_move")}
        d = settings.integrator_dict()
        d["type"] = self.integrator
        d["guiding"] = "octree"  # a configuration without 'guiding' is Mitsuba's default
        if sppc == 0:
            d["sppc"] = 0  # integrator_dict turns 0 into spp
        d.update(props)
        return obj, mi.load_dict(d)

    # -- one step, timed ---------------------------------------------------------------------
    def step(self, obj, integ, vertices: np.ndarray, view_ids: list[int], seed: int) -> dict:
        v = mi.Float(np.asarray(vertices, np.float32).ravel())
        dr.enable_grad(v)
        obj._set_vertices(v)
        params = obj.renderer.params
        detail = integ.proj_detail
        built0, build0 = detail.builds, (detail.build_seconds, detail.build_cpu_seconds)
        fwd = bwd = np.zeros(2)  # (wall, cpu) seconds
        for k, view in enumerate(view_ids):
            if k:
                obj.renderer.object.recompute_vertex_normals()
            obj.renderer._set_lights(view)
            t0 = np.array([time.perf_counter(), time.process_time()])
            img = mi.render(obj.renderer.scene, params, sensor=obj.renderer.sensors[view], seed=seed + k, spp=0,
                            integrator=integ)
            loss = dr.mean(dr.square(obj._tone(img) - obj.targets[view]), axis=None).array / len(view_ids)
            dr.eval(loss)
            dr.sync_thread()
            t1 = np.array([time.perf_counter(), time.process_time()])
            dr.backward(loss)
            dr.eval(dr.grad(v))
            dr.sync_thread()
            fwd, bwd = fwd + t1 - t0, bwd + np.array([time.perf_counter(), time.process_time()]) - t1
        grad = np.array(dr.grad(v), np.float64).reshape(-1, 3)
        dr.disable_grad(v)
        guide = np.array([detail.build_seconds - build0[0], detail.build_cpu_seconds - build0[1]])
        return {"forward": fwd, "backward": bwd, "guiding": guide, "builds": detail.builds - built0, "grad": grad}

    def shadow_part(self, integ, obj, vertices, view_ids, grads_in, seed: int) -> np.ndarray:
        """The indirect part alone, backpropagated from the reference's adjoint with the guiding
        the last step built or reused (so primal noise and guiding cost stay out of it)."""
        detail = integ.proj_detail
        saved = (integ.sppc, integ.sppp, detail.reuse, {k: e["uses"] for k, e in detail.cache.items()})
        integ.sppc = integ.sppp = 0
        detail.reuse = 1 << 30
        try:
            return self.reference(obj, integ, vertices, view_ids, grads_in, [seed])
        finally:
            integ.sppc, integ.sppp, detail.reuse = saved[:3]
            for k, uses in saved[3].items():
                detail.cache[k]["uses"] = uses

    # -- reference ---------------------------------------------------------------------------
    def grad_in(self, obj, view: int, n_views: int):
        """dLoss/dImage of a ``--ref-spp`` primal render (fixed for every reference pass)."""
        with dr.suspend_grad():
            img = mi.render(obj.renderer.scene, sensor=obj.renderer.sensors[view], seed=777 + view,
                            spp=self.args.ref_spp, integrator=mi.load_dict({"type": "path", "max_depth": self.args.max_depth,
                                                                             "hide_emitters": True}))
        img = mi.TensorXf(img)
        dr.enable_grad(img)
        loss = dr.mean(dr.square(obj._tone(img) - obj.targets[view]), axis=None).array / n_views
        dr.backward(loss)
        return mi.TensorXf(dr.grad(img))

    def reference(self, obj, integ, vertices: np.ndarray, view_ids: list[int], grads_in, seeds) -> np.ndarray:
        total = np.zeros((len(vertices), 3))
        for seed in seeds:
            v = mi.Float(np.asarray(vertices, np.float32).ravel())
            dr.enable_grad(v)
            obj._set_vertices(v)
            for k, view in enumerate(view_ids):
                if k:
                    obj.renderer.object.recompute_vertex_normals()
                obj.renderer._set_lights(view)
                integ.render_backward(obj.renderer.scene, obj.renderer.params, grads_in[k],
                                      sensor=obj.renderer.sensors[view], seed=seed + k, spp=0)
            total += np.array(dr.grad(v), np.float64).reshape(-1, 3)
            dr.disable_grad(v)
        return total / len(seeds)


def _summarise(spec: str, rows: list[dict], base_grads: dict, ref: dict, every: int, base_row: dict | None,
               shadows: bool, process=None) -> dict:  # noqa: C901
    """Means over a configuration's steps; with ``every`` > 1 the cost and full-gradient
    agreement are those of one step with shadow terms and ``every - 1`` without."""
    mean = lambda key: np.mean([r[key] for r in rows], 0)  # noqa: E731  (wall, cpu)
    fwd, bwd, guide = mean("forward"), mean("backward"), mean("guiding")
    full = [agreement(r["grad"], ref["full"]) for r in rows]
    if every > 1 and base_row is not None:
        fwd = (fwd + (every - 1) * base_row["times"][0]) / every
        bwd = (bwd + (every - 1) * base_row["times"][1]) / every
        guide /= every
        base = [agreement(base_grads[s], ref["full"]) for s in range(len(rows))]
        full = [((c[0] + (every - 1) * b[0]) / every, (c[1] + (every - 1) * b[1]) / every) for c, b in zip(full, base)]
    row = {"config": spec, "forward": fwd[1], "backward": bwd[1], "guiding": guide[1], "step": fwd[1] + bwd[1],
           "wall": {"forward": fwd[0], "backward": bwd[0], "guiding": guide[0], "step": fwd[0] + bwd[0]},
           "builds": int(sum(r["builds"] for r in rows)),
           "cos": float(np.mean([c[0] for c in full])), "norm": float(np.mean([c[1] for c in full])),
           "shadow_cos": 0.0, "shadow_norm": 0.0, "shadow_error": 1.0, "shadow_mean_cos": 0.0}
    if process is not None:
        row["opt_cos"] = row["opt_cos_min"] = row["opt_mean_cos"] = agreement(process(ref["base"]),
                                                                              process(ref["full"]))[0]
    row["ratio"] = row["step"] / base_row["step"] if base_row else 1.0
    row["wall"]["ratio"] = row["wall"]["step"] / base_row["wall"]["step"] if base_row else 1.0
    row["times"] = (fwd, bwd)
    row["work_variance"] = 0.0
    if shadows:
        parts = [r["shadow"] for r in rows]
        target = ref["indirect"]
        sh = [agreement(p, target) for p in parts]
        err = [float(np.sum((p - target) ** 2) / np.sum(target ** 2)) for p in parts]
        err = [(e + (every - 1)) / every for e in err] if every > 1 else err
        row.update(shadow_cos=float(np.mean([c[0] for c in sh])), shadow_norm=float(np.mean([c[1] for c in sh])),
                   shadow_error=float(np.mean(err)), shadow_mean_cos=agreement(np.mean(parts, 0), target)[0])
        row["shadow_errors"] = err
        if process is not None:  # what the optimiser steps along: the clean rest plus this shadow part
            target_p = process(ref["full"])
            opt = [agreement(process(ref["base"] + p), target_p)[0] for p in parts]
            if every > 1:
                opt = [(o + (every - 1) * agreement(process(ref["base"]), target_p)[0]) / every for o in opt]
            mean_part = np.mean(parts, 0) if every == 1 else np.mean(parts, 0) / every
            row.update(opt_cos=float(np.mean(opt)), opt_cos_min=float(np.min(opt)),
                       opt_mean_cos=agreement(process(ref["base"] + mean_part), target_p)[0])
        if base_row is not None:  # the shadow term's error times its extra seconds: lower is better
            row["work_variance"] = row["shadow_error"] * max(row["step"] - base_row["step"], 0.0)
    return row


def run(args) -> int:
    chosen = variant.choose()
    t_start = time.perf_counter()
    bench = _Bench(args)
    a = args
    print(f"{a.mesh} {bench.truth_faces} faces under {a.envmap} (strength {a.strength:g}), {a.resolution} px, "
          f"{a.views} views, {a.views_per_step} per step, max_depth {a.max_depth}, spp {a.spp}, sppp {a.sppp}; "
          f"self-shadowing {100 * bench.self_shadowing:.1f} %; load {os.getloadavg()[0]:.1f}", flush=True)
    # every step differentiates the same views with its own seed: averaging the steps' gradients
    # shows a configuration's bias (what more samples would not remove)
    views = sorted({round(k * a.views / a.views_per_step) % a.views for k in range(a.views_per_step)})
    t0 = time.perf_counter()
    base_obj, base_int = bench.objective({"sppi": 0}, sppc=a.ref_spp, sppp=a.ref_spp)
    ind_obj, ind_int = bench.objective({"sppi": a.ref_sppi}, sppc=0, sppp=0)
    gin = [bench.grad_in(base_obj, v, len(views)) for v in views]
    ref_base = bench.reference(base_obj, base_int, bench.estimate.vertices, views, gin, [100_000])
    ref_ind = bench.reference(ind_obj, ind_int, bench.estimate.vertices, views, gin,
                              [200_000 + 97 * r for r in range(a.ref_rounds)])
    ref = {"base": ref_base, "indirect": ref_ind, "full": ref_base + ref_ind}
    ref_share = float(np.linalg.norm(ref_ind) / np.linalg.norm(ref["full"]))
    print(f"reference: {time.perf_counter() - t0:.0f} s; the indirect (shadow) part is {100 * ref_share:.1f} % of "
          f"the reference gradient's norm", flush=True)

    system = LaplacianSystem(bench.estimate.faces, len(bench.estimate.vertices), a.smoothing)

    def process(g: np.ndarray) -> np.ndarray:  # the optimiser's per-vertex cap, then its smoothing
        return system.solve(clip_outliers(g, a.clip))

    configs = [c.strip() for c in a.configs.split(";") if c.strip()]
    configs = ["sppi=0"] + [c for c in configs if c != "sppi=0"]  # the baseline every ratio divides by
    results, base_grads = [], {}
    header = (f"{'configuration':<44}{'fwd s':>7}{'bwd s':>7}{'guide s':>8}{'step s':>8}{'x no-sh':>8}{'wall x':>7}"
              f"{'cos':>7}{'|g|/ref':>8}{'sh cos':>8}{'sh |g|':>8}{'sh err':>8}{'sh mean':>8}{'err x s':>8}{'opt cos':>8}{'min':>7}{'mean':>7}")
    print(header, flush=True)
    for spec in configs:
        config = parse_config(spec)
        reuse, every = config.get("guiding_reuse", 1), config.get("every", 1)
        rows = []
        # one integrator per configuration, as per level in the optimiser; an untimed first step
        # compiles its kernels (and estimates the octree's mass threshold, once per integrator)
        obj, integ = bench.objective(config)
        integ.proj_detail.hold = True
        bench.step(obj, integ, bench.estimate.vertices, views, 77)
        for s in range(a.steps):
            seed = 1000 * (s + 1)
            integ.proj_detail.clear()
            if reuse > 1:  # warm the cache on the mesh as it was reuse - 1 steps ago (untimed)
                old = bench.estimate.vertices - (reuse - 1) * bench.step_move
                warm = bench.step(obj, integ, old, views, seed + 500)
            r = bench.step(obj, integ, bench.estimate.vertices, views, seed)
            if config.get("sppi", 0) > 0:
                r["shadow"] = bench.shadow_part(integ, obj, bench.estimate.vertices, views, gin, seed)
            if reuse > 1:
                r["guiding"] = warm["guiding"] / reuse  # amortised: one build per reuse steps
                r["backward"] += r["guiding"]
            if spec == "sppi=0":
                base_grads[s] = r["grad"]
            rows.append(r)
        row = _summarise(spec, rows, base_grads, ref, every, results[0] if results else None,
                         config.get("sppi", 0) > 0, process)
        results.append(row)
        print(f"{spec:<44}{row['forward']:>7.2f}{row['backward']:>7.2f}{row['guiding']:>8.2f}{row['step']:>8.2f}"
              f"{row['ratio']:>7.1f}x{row['wall']['ratio']:>6.1f}x{row['cos']:>7.3f}{row['norm']:>8.3f}{row['shadow_cos']:>8.3f}"
              f"{row['shadow_norm']:>8.3f}{row['shadow_error']:>8.2f}{row['shadow_mean_cos']:>8.3f}{row['work_variance']:>8.2f}"
              f"{row['opt_cos']:>8.4f}{row['opt_cos_min']:>7.3f}{row['opt_mean_cos']:>7.3f}",
              flush=True)
    print(f"per step ({len(views)} views, means of {a.steps} steps), CPU seconds of all the process's threads "
          f"(steadier than wall-clock time on a shared machine): fwd = primal render + loss; bwd = backward "
          f"pass, guide = its guiding construction; x no-sh = step time over sppi=0's, wall x = the same in "
          f"wall-clock time. cos, |g|/ref: the step's "
          f"vertex gradient against the reference; sh: the shadow part alone, with the step's seed and guiding "
          f"but the reference's adjoint (dLoss/dImage of a {a.ref_spp}-spp render): cos, norm ratio, relative squared error |g - ref|^2 / |ref|^2 (1 = no "
          f"shadow term), the cosine of the mean over the steps, and err x s = the squared error times the "
          f"step's extra seconds over sppi=0 (an unbiased term's cost of accuracy: lower is better); opt cos "
          f"(mean, min over the steps): the optimiser's direction (gradient capped at its {a.clip:g}th percentile, "
          f"smoothed with lambda {a.smoothing:g}) of the reference's shadow-free part plus this shadow part, "
          f"against that of the reference (sppi=0: the shadow-free part alone); mean: the same with the mean of the "
          f"steps' shadow parts (what averaging over steps leaves: the bias). {time.perf_counter() - t_start:.0f} s in all",
          flush=True)
    bounces = "direct" if a.max_depth <= 2 else f"{a.max_depth - 2} bounce{'s' if a.max_depth > 3 else ''}"
    scene = f"{a.mesh} {a.faces / 1000:g}k, {a.resolution} px, {a.envmap}, {bounces}"
    base = results[0]
    _records.write_record(
        "hdr", title="HDR-lit step cost", variant=chosen, merge_on="scene",
        show=["scene", "self-shadowed %", "samples", "without s", "with s", "ratio", "shadow error"],
        context="CPU seconds of a geometry step (2 views) without and with shadow gradients; shadow error: relative "
                "squared error against a high-sample reference",
        rows=[{"scene": scene, "self-shadowed %": round(100 * bench.self_shadowing, 1),
               "samples": parse_config(r["config"]).get("sppi"), "without s": round(base["step"], 2),
               "with s": round(r["step"], 2), "ratio": round(r["ratio"], 2), "shadow error": round(r["shadow_error"], 2),
               "opt cos without / with": f"{base['opt_cos']:.3f} / {r['opt_cos']:.3f}"} for r in results[1:]])
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"args": {k: str(v) for k, v in vars(a).items()},
                                     "self_shadowing": bench.self_shadowing, "faces": bench.truth_faces,
                                     "reference_indirect_share": ref_share, "rows": results}, indent=2,
                                    default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    return 0
