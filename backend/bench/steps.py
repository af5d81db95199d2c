"""Step cost split: where a geometry step's time goes (forward, backward, silhouette sampling, host work), on an HDR-lit scene.

The scene is ``bench hdr``'s: a shared mesh simplified to ``--faces`` under a Poly Haven map,
the estimate displaced from it along its normals, ``--views`` cameras at ``--resolution``.
Each configuration (``--configs``: ``;``-separated integrator properties, as ``bench hdr``
takes them) runs ``--steps`` geometry steps exactly as a level does: ``Objective.loss_and_grad``
over ``--views-per-step`` views, the per-vertex gradient cap and the Large Steps update
(``VertexOptimizer``), after ``--warmup`` untimed steps that compile the kernels. A step's
parts (``objective.StepTimer``; each ends in a sync):

- ``forward``: the primal render and the loss;
- ``backward``: the backward pass less ``silhouette``;
- ``silhouette``: the primarily visible silhouette term up to its backward traversal: the
  precomputation for the view (Mitsuba's ``init_primarily_visible_silhouette``) and the
  sampling (``render_primarily_visible_silhouette``); work still pending when it starts is
  charged to ``backward``, and where Mitsuba's plugin leaves the radiance difference lazy
  (``main``) its tracing lands in ``backward`` too;
- ``scene update``: new vertex positions, the BVH and the normals;
- ``read-back``: losses and gradients to NumPy;
- ``solve``: the gradient cap and the Large Steps solve;
- ``other``: the rest of the step's wall time (Python).

Every configuration runs twice, side by side: ``main`` with the integrator's primarily visible
silhouette as Mitsuba's plugin computes it (``silhouette_once`` off: the step as it was before
``render.projective`` took the term over) and ``new`` with the project's term. Prints one row
per configuration and path (median seconds per step of each part over the timed steps, and
main's step time over new's) and writes the ``steps`` record."""

from __future__ import annotations

import os
import statistics
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import variant
from ..optimize.objective import StepTimer
from ..optimize.steps import VertexOptimizer, clip_outliers
from . import _records
from .hdr import _Bench, add_scene_arguments, parse_config

PARTS = ("forward", "backward", "silhouette", "scene update", "read-back", "solve", "other")


def add_arguments(parser) -> None:
    add_scene_arguments(parser)
    parser.set_defaults(envmap="forest", faces=10000, resolution=128, views=16, max_depth=3)
    parser.add_argument("--ref-spp", type=int, default=64, help="samples of the target renders (default: %(default)s)")
    parser.add_argument("--steps", type=int, default=8, help="timed steps per configuration (default: %(default)s)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps first (default: %(default)s)")
    parser.add_argument("--configs", default="sppi=0;sppi=12,guiding=none", help="default: %(default)s")


def _timed(owner, name: str, timer: StepTimer) -> None:
    """Charge ``owner.name``'s calls to the timer's ``silhouette`` part (pending work first
    finishes outside it)."""
    inner = getattr(owner, name)

    def timed(*args):
        dr.sync_thread()
        with timer.part("silhouette"):
            return inner(*args)

    setattr(owner, name, timed)


def measure(bench: _Bench, config: dict, args, path: str = "new") -> dict:
    """Median seconds per step of every part, over ``args.steps`` timed steps of ``config``
    on ``path`` ("main": Mitsuba's own primarily visible silhouette term)."""
    obj, integrator = bench.objective(config)
    integrator.silhouette_once = path == "new"
    renderer = obj.renderer

    def render_split(view, seed, params):  # the level's render, with this configuration's integrator
        renderer._set_lights(view)
        return mi.render(renderer.scene, params, sensor=renderer.sensors[view], seed=seed, spp=0,
                         integrator=integrator)

    renderer.render_split = render_split
    timer = obj.timer = StepTimer()
    _timed(integrator.proj_detail, "init_primarily_visible_silhouette", timer)
    _timed(integrator, "render_primarily_visible_silhouette", timer)
    opt = VertexOptimizer(bench.estimate.vertices, bench.estimate.faces, args.smoothing, bench.edge * args.step_move)
    vertices = bench.estimate.vertices.copy()
    n, k = len(bench.views), args.views_per_step
    rows = []
    for step in range(args.warmup + args.steps):
        timer.seconds.clear()
        ids = [(step * k + j) % n for j in range(k)]
        start = time.perf_counter()
        _, grad, _ = obj.loss_and_grad(vertices, ids, 1000 + step, geometry=True, material=False)
        with timer.part("solve"):
            vertices = opt.step(clip_outliers(grad, args.clip))
        wall = time.perf_counter() - start
        if step < args.warmup:
            continue
        parts = dict(timer.seconds)
        parts["backward"] = parts.get("backward", 0.0) - parts.get("silhouette", 0.0)
        parts["other"] = wall - sum(parts.values())
        parts["step"] = wall
        rows.append(parts)
    del obj
    dr.flush_malloc_cache()
    return {p: statistics.median(r.get(p, 0.0) for r in rows) for p in (*PARTS, "step")}


def run(args) -> int:
    chosen = variant.choose()
    args.ref_rounds, args.ref_sppi = 1, 0  # _Bench's reference options, unused here
    bench = _Bench(args)
    a = args
    print(f"{a.mesh} {bench.truth_faces} faces under {a.envmap}, {a.resolution} px, {a.views} views, "
          f"{a.views_per_step} per step, max_depth {a.max_depth}, spp {a.spp}, sppp {a.sppp}; "
          f"{a.steps} timed steps each; {chosen}; load {os.getloadavg()[0]:.1f}", flush=True)
    header = ["config", "path", "step s", *PARTS, "main/new"]
    print("  ".join(f"{h:>12}" for h in header))
    rows = []
    for spec in [c.strip() for c in a.configs.split(";") if c.strip()]:
        main = None
        for path in ("main", "new"):
            m = measure(bench, parse_config(spec), a, path)
            main = main or m["step"]
            speedup = round(main / m["step"], 2)
            rows.append({"config": spec, "path": path, "step s": round(m["step"], 4),
                         **{p: round(m[p], 4) for p in PARTS},
                         "host share": round((m["scene update"] + m["read-back"] + m["solve"] + m["other"]) / m["step"], 3),
                         "main/new": speedup})
            print("  ".join(f"{v:>12}" if isinstance(v, str) else f"{v:12.4f}" for v in
                            [spec, path, m["step"], *(m[p] for p in PARTS), speedup]), flush=True)
    _records.write_record(
        "steps", title="Step cost split",
        context=(f"an HDR-lit geometry step ({a.mesh}, {bench.truth_faces} faces, {a.resolution} px, "
                 f"{a.views_per_step} views, one bounce) in parts, median s; host: scene update, read-back, solve, "
                 "Python; main: Mitsuba's primarily visible silhouette term, new: render.projective's"),
        rows=rows, show=["config", "path", "step s", "forward", "backward", "silhouette", "host share", "main/new"], command=f"python -m backend bench steps --faces {a.faces} --resolution {a.resolution}",
        variant=chosen)
    return 0
