"""Camera refinement: perturbed cameras of a synthetic capture recovered against its true mesh and material.

A synthetic capture (the built-in object, ``--views`` cameras at ``--resolution`` px, the
paper's point lights, a textured albedo) is rendered with exact cameras; each frame's camera is
then perturbed by ``--rotation`` degrees (a random axis through the camera centre) and
``--translation`` % of its distance to the object (a random direction). With the true mesh and
its per-vertex material fixed, ``CameraFit.refine`` (backend.optimize.camera_fit) runs
``--rounds`` refinements of ``--sweeps`` sweeps at ``--size`` px and path depth ``--max-depth``
(0: the capture's own, the light transport a run whose effects match the scene renders), the last followed by
``--newton`` Gauss-Newton steps on each frame's pose (backend.optimize.camera_newton). The errors
against the true cameras are taken after the similarity that best aligns the camera centres (the
gauge of a run whose mesh follows the cameras) and, since here the mesh is fixed and so fixes the
gauge, also without one:
rotation in degrees, translation in % of the camera distance, and the mesh's reprojection in
pixels of the frames. Writes the ``cameras`` record."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..capture.load import load_capture
from ..geometry.mesh import load_mesh
from ..optimize.camera_fit import CameraFit
from ..optimize.camera_model import pose_errors, reprojection_px, rotation
from ..optimize.views import ViewSet
from ..render.scene import RenderSettings
from ..render.views import display_field
from . import _records


class FixedMaterial:
    """A display mesh's per-vertex material as the objective takes a material: nothing trainable."""

    KIND = "fixed"
    trainable = ()
    light_factor = 1.0

    def __init__(self, mesh):
        self.field = display_field(mesh)

    def parameters(self) -> dict:
        return {}

    def attach(self, params):
        return params


def perturb(cameras, centre, rotation_deg: float, translation_pct: float, seed: int = 0):
    """Each camera turned by ``rotation_deg`` about a random axis through its centre and moved by
    ``translation_pct`` % of its distance to ``centre`` in a random direction."""
    rng = np.random.default_rng(seed)
    out = []
    for c in cameras:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        step = rng.normal(size=3)
        step /= np.linalg.norm(step)
        m = np.asarray(c.camera_to_world, np.float64).copy()
        m[:3, :3] = rotation(np.radians(rotation_deg) * axis) @ m[:3, :3]
        m[:3, 3] += translation_pct / 100.0 * np.linalg.norm(c.centre - centre) * step
        out.append(type(c)(c.width, c.height, c.fx, c.fy, c.cx, c.cy, m, dict(c.distortion)))
    return out


def recovery(capture_root: Path, *, rotation_deg: float = 1.0, translation_pct: float = 1.0, size: int = 64,
             sweeps: int = 6, rounds: int = 2, seed: int = 0, spp: int = 16, intrinsics: bool = True,
             newton: int = 0, max_depth: int = 2) -> dict:
    """Perturb the capture's cameras, refine them against its true mesh and material, and
    return the errors before and after (``pose_errors``) and the mean reprojection error (px).
    ``max_depth``: the refinement's path depth (2: direct light, ``direct_projective``; more:
    ``prb_projective``)."""
    capture = load_capture(capture_root)
    truth_mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    truth = [f.camera for f in capture.frames]
    lo, hi = truth_mesh.bounds()
    centre = 0.5 * (lo + hi)
    for frame, cam in zip(capture.frames, perturb(truth, centre, rotation_deg, translation_pct, seed)):
        frame.camera = cam
    fit = CameraFit([f.name for f in capture.frames], [f.camera for f in capture.frames], centre)
    viewset = ViewSet(capture, size)
    material = FixedMaterial(truth_mesh)
    settings = RenderSettings(spp=spp, max_depth=max_depth, sppc=spp, sppp=4,
                              integrator="direct_projective" if max_depth <= 2 else "prb_projective")
    points = truth_mesh.vertices

    def reproj(cams):
        return float(np.mean([reprojection_px(t, c, points) for t, c in zip(truth, cams)]))

    before = {**pose_errors(fit.cameras(), truth, centre), "reprojection_px": reproj(fit.cameras())}
    start = time.perf_counter()
    history = []
    for r in range(rounds):
        history.append(fit.refine(truth_mesh, material, viewset.at(size), settings, capture.environment,
                                  sweeps=sweeps, seed=seed + 17 * r, intrinsics=intrinsics,
                                  newton=newton if r == rounds - 1 else 0))
    after = {**pose_errors(fit.cameras(), truth, centre), "reprojection_px": reproj(fit.cameras())}
    unaligned = pose_errors(fit.cameras(), truth, centre, align=False)
    return {"before": before, "after": after, "after_unaligned": unaligned,
            "seconds": round(time.perf_counter() - start, 2),
            "history": history, "focal_scale": float(np.exp(fit.correction.sigma)),
            "principal": fit.correction.principal.tolist()}


def add_arguments(parser) -> None:
    parser.add_argument("--out", type=Path, required=True, help="scratch folder (the synthetic capture)")
    parser.add_argument("--views", type=int, default=12)
    parser.add_argument("--resolution", type=int, default=128, help="the capture's frames (px)")
    parser.add_argument("--size", type=int, default=128, help="the refinement's images (px)")
    parser.add_argument("--rotation", type=float, default=1.0, help="degrees (default %(default)s)")
    parser.add_argument("--translation", type=float, default=1.0, help="%% of the camera distance (default %(default)s)")
    parser.add_argument("--sweeps", type=int, default=8)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--newton", type=int, default=6,
                        help="Gauss-Newton steps on each frame's pose after the last refinement's sweeps (0: none)")
    parser.add_argument("--max-depth", type=int, default=2,
                        help="the refinement's path depth (2: direct light only; 0: the capture's own, as a "
                             "run whose effects match the scene)")
    parser.add_argument("--intrinsics", action="store_true",
                        help="refine the shared focal length and principal point too (the perturbation is poses only)")


def run(args) -> int:
    from ..synth.capture import SynthSpec, synthesize  # noqa: PLC0415  (only this benchmark synthesises)

    capture = Path(args.out) / "capture"
    if not (capture / "capture.json").is_file():
        capture.mkdir(parents=True, exist_ok=True)
        synthesize(SynthSpec(views=args.views, resolution=args.resolution, spp=64, albedo="pattern", held_out=0), capture,
                   lambda *a, **k: None)
    spec = load_capture(capture).provenance.get("spec", {})
    depth = args.max_depth or int(spec.get("max_depth", 2))
    out = recovery(capture, rotation_deg=args.rotation, translation_pct=args.translation, size=args.size,
                   sweeps=args.sweeps, rounds=args.rounds, seed=args.seed, intrinsics=args.intrinsics,
                   newton=args.newton, max_depth=depth)
    rows = []
    for when in ("before", "after"):
        e = out[when]
        rows.append({"cameras": when, "rotation mean (deg)": round(e["rotation_deg"]["mean"], 4),
                     "rotation max (deg)": round(e["rotation_deg"]["max"], 4),
                     "translation mean (%)": round(e["translation_pct"]["mean"], 4),
                     "translation max (%)": round(e["translation_pct"]["max"], 4),
                     "reprojection (px)": round(e["reprojection_px"], 4)})
    e = out["after_unaligned"]
    rows.append({"cameras": "after, not aligned", "rotation mean (deg)": round(e["rotation_deg"]["mean"], 4),
                 "rotation max (deg)": round(e["rotation_deg"]["max"], 4),
                 "translation mean (%)": round(e["translation_pct"]["mean"], 4),
                 "translation max (%)": round(e["translation_pct"]["max"], 4),
                 "reprojection (px)": round(out["after"]["reprojection_px"], 4)})
    for row in rows:
        print(row)
    _records.write_record(
        "cameras", title="Camera refinement",
        context=(f"built-in object, {args.views} views at {args.resolution} px, cameras perturbed by "
                 f"{args.rotation} deg and {args.translation} % of the distance, true mesh and material fixed; "
                 f"{args.rounds} refinements of {args.sweeps} sweeps at {args.size} px and path depth {depth} (the "
                 f"capture's {spec.get('max_depth', '?')}), the last followed by "
                 f"{args.newton} Gauss-Newton steps per frame, intrinsics "
                 f"{'refined' if args.intrinsics else 'fixed'}; errors after a similarity alignment of the centres "
                 "(and, the mesh being fixed, without one)"),
        rows=rows, scalars={"seconds": out["seconds"], "focal_scale": round(out["focal_scale"], 6),
                            "newton_seconds": round(sum(h["newton_seconds"] for h in out["history"]), 2)})
    return 0
