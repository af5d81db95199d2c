"""Sample counts of a geometry step: the gradient's value per second of primal, interior and silhouette samples.

A geometry step spends samples in three places: the primal image (``P``, the sensors' count:
``RenderSettings.primal_spp``), the interior of the backward pass (``C``, the integrator's
``sppc``) and the primarily visible silhouette term (``S``, ``sppp``). On ``bench steps``'
HDR-lit scene (``--faces``, ``--resolution``, ``--max-depth``, the estimate ``--offset`` from
the truth) each configuration ``P,C,S`` (``--configs``, ``;``-separated) takes ``--seeds``
steps' gradients of the same two views, as a level's step computes them
(``Objective.loss_and_grad``, the gradient cap and the Large Steps solve: the direction a
step moves the vertices along), timed interleaved with the other configurations so that
load drifts fall on all of them. The reference is the mean of ``--ref-seeds`` such
directions at ``--ref-spp`` primal and interior samples and 16 silhouette samples.

Per configuration: the median seconds of a step, the mean cosine ``c`` of its directions
against the reference, the signal-to-noise ratio ``c^2 / (1 - c^2)`` (averaging ``k``
independent directions multiplies it by ``k``, at ``k`` times the cost) and that ratio per
second of a step, the figure to compare. Writes the ``samples`` record."""

from __future__ import annotations

import statistics
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import variant
from ..optimize.steps import LaplacianSystem, clip_outliers
from ..render.scene import sensor_dict
from . import _records
from .hdr import _Bench, add_scene_arguments

VIEWS = (0, 5)


def add_arguments(parser) -> None:
    add_scene_arguments(parser)
    parser.set_defaults(envmap="forest", faces=10000, resolution=128, views=16, max_depth=3)
    parser.add_argument("--configs", default="16,16,4;32,16,2;32,16,4;16,16,2;32,32,2",
                        help="P,C,S per configuration: primal, interior and silhouette samples per pixel "
                             "(default: %(default)s)")
    parser.add_argument("--seeds", type=int, default=8, help="timed steps per configuration (default: %(default)s)")
    parser.add_argument("--ref-spp", type=int, default=128, help="the reference's P and C, and the targets' samples (default: %(default)s)")
    parser.add_argument("--ref-seeds", type=int, default=10, help="directions averaged (default: %(default)s)")


def parse_counts(spec: str) -> list[tuple[int, int, int]]:
    """'16,16,4;32,16,2' -> [(16, 16, 4), (32, 16, 2)]."""
    out = []
    for item in [s.strip() for s in spec.split(";") if s.strip()]:
        counts = tuple(int(x) for x in item.split(","))
        if len(counts) != 3 or min(counts) < 1:
            raise ValueError(f"'{item}': give three positive counts P,C,S")
        out.append(counts)
    return out


class _Config:
    """One configuration's objective on the bench's scene, its primal at ``P`` samples."""

    def __init__(self, bench: _Bench, system: LaplacianSystem, clip: float, counts: tuple[int, int, int]):
        primal, sppc, sppp = counts
        self.objective, integrator = bench.objective({"sppi": 0}, sppc=sppc, sppp=sppp)
        renderer = self.objective.renderer
        renderer.sensors = [mi.load_dict(sensor_dict(v.camera, primal)) for v in bench.views]

        def render_split(view, seed, params):
            renderer._set_lights(view)
            return mi.render(renderer.scene, params, sensor=renderer.sensors[view], seed=seed, spp=0,
                             integrator=integrator)

        renderer.render_split = render_split
        self.vertices, self.system, self.clip = bench.estimate.vertices, system, clip

    def step(self, seed: int) -> tuple[np.ndarray, float]:
        start = time.perf_counter()
        _, grad, _ = self.objective.loss_and_grad(self.vertices, list(VIEWS), seed, geometry=True, material=False)
        direction = self.system.solve(clip_outliers(grad, self.clip))
        return direction, time.perf_counter() - start


def cosine(a: np.ndarray, b: np.ndarray) -> float:
    return float(a.ravel() @ b.ravel()) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-30)


def run(args) -> int:
    chosen = variant.choose()
    try:
        configs = parse_counts(args.configs)
    except ValueError as err:
        print(f"error: --configs {err}", file=sys.stderr)
        return 2
    args.ref_rounds, args.ref_sppi = 1, 0  # _Bench's shadow-reference options, unused here
    bench = _Bench(args)
    system = LaplacianSystem(bench.estimate.faces, len(bench.estimate.vertices), args.smoothing)
    ref = _Config(bench, system, args.clip, (args.ref_spp, args.ref_spp, 16))
    reference = np.mean([ref.step(90_000 + 7 * k)[0] for k in range(args.ref_seeds)], axis=0)
    self_cos = statistics.mean(cosine(ref.step(80_000 + 7 * k)[0], reference) for k in range(2))
    del ref
    dr.flush_malloc_cache()
    runs = [_Config(bench, system, args.clip, c) for c in configs]
    for r in runs:
        r.step(1)  # compiles
    directions, seconds = [[] for _ in runs], [[] for _ in runs]
    for k in range(args.seeds):
        for i, r in enumerate(runs):
            d, s = r.step(1000 + 7 * k)
            directions[i].append(d)
            seconds[i].append(s)
    a = args
    print(f"{a.mesh} {bench.truth_faces} faces under {a.envmap}, {a.resolution} px, offset {a.offset}, "
          f"max_depth {a.max_depth}; {a.seeds} steps each; reference {a.ref_seeds} x {a.ref_spp} spp "
          f"(a single one at cosine {self_cos:.3f}); {chosen}", flush=True)
    print(f"{'P,C,S':>10} {'step s':>8} {'cosine':>7} {'SNR':>7} {'SNR/s':>8}")
    rows = []
    for c, ds, ss in zip(configs, directions, seconds):
        cos = statistics.mean(cosine(d, reference) for d in ds)
        snr = cos * cos / max(1 - cos * cos, 1e-9)
        step = statistics.median(ss)
        rows.append({"P,C,S": ",".join(map(str, c)), "step s": round(step, 4), "cosine": round(cos, 3),
                     "SNR": round(snr, 3), "SNR per s": round(snr / step, 2)})
        print(f"{rows[-1]['P,C,S']:>10} {step:8.3f} {cos:7.3f} {snr:7.3f} {snr / step:8.2f}", flush=True)
    _records.write_record(
        "samples", title="Sample counts of a geometry step", merge_on="scene",
        context=(f"gradient directions of an HDR-lit step ({a.mesh}, {bench.truth_faces} faces, {a.resolution} px, "
                 "2 views) against a high-sample reference; P primal, C interior, S silhouette samples per pixel; "
                 "SNR = c^2/(1-c^2), per second of a step"),
        rows=[{"scene": f"depth {a.max_depth}, offset {a.offset}", **r} for r in rows],
        show=["scene", "P,C,S", "step s", "SNR per s"], variant=chosen)
    return 0
