"""Material reconstruction against known truth (dragon, textured glossy): novel-view, albedo, relit scores.

``python -m backend bench material [--geometry RUN/result.ply]`` synthesises (once, cached in the output folder) a paper-style capture: the dragon with a
textured albedo and a glossy specular lobe under two point lights per camera, plus
held-out views and relit views under a second sky. The material is then fitted on the
given geometry (the truth by default, or ``--geometry`` a reconstruction in the capture's
frame) with the staged schedule (constants, textured diffuse with highlight masking,
textured specular), and scored: novel-view PSNR on the held-out views, albedo RMSE
against the truth's vertex colours, relit PSNR (the held-out cameras under the relit
environment alone). References are the truth mesh and material rendered here the same way,
at the same samples per pixel. Writes ``result.glb``, the display mesh,
the material state and ``report.json`` into ``OUT/run``."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from .. import fsio, variant
from ..capture.images import read_linear_rgb, read_mask, read_rgba
from ..capture.load import load_capture
from ..events import Emitter
from ..geometry.mesh import load_mesh, save_mesh
from ..material import stages
from ..material.export import write_glb
from ..material.model import MeshColorMaterial
from ..metrics.geometry import corresponding_albedo
from ..metrics.image import albedo_rmse, image_metrics
from ..render.fields import VertexField
from ..render.scene import RenderSettings, SceneRenderer
from ..synth.capture import SynthSpec, synthesize
from . import _material_table, _records
from ._data import SHARED_DATA

REPO = Path(__file__).resolve().parents[2]
DRAGON = SHARED_DATA / "meshes" / "shapefromtracing" / "dragon.obj"


@dataclass
class MaterialBench:
    mesh: str = str(DRAGON)
    up: str = "y"
    views: int = 32  # x 2 point lights each (the paper's layout)
    held_out: int = 4
    resolution: int = 128
    truth_spp: int = 256
    max_depth: int = 4
    spp: int = 16  # training renders
    # scored renders (reconstruction and truth alike): enough samples that the metric's own noise
    # stays well below the differences it scores
    eval_spp: int = 4096
    mesh_color_resolution: int = 1
    constant_iterations: int = 48
    diffuse_iterations: int = 160
    specular_iterations: int = 96
    lr: float = 0.1
    variance_weight: float = 0.1
    smoothness_weight: float = 1.0
    edge_erosion: int = 1
    robust: float = 0.0
    geometry: str = ""  # a reconstructed mesh; empty: the truth
    seed: int = 0


HELP = {"mesh": "the object (its truth material: procedural albedo pattern, specular 0.25, roughness 0.35)",
        "up": "the mesh file's up axis (z or y)", "truth_spp": "samples per pixel of the synthetic capture",
        "spp": "samples per pixel of the training renders", "eval_spp": "samples per pixel of the scored renders",
        "mesh_color_resolution": "mesh-color resolution r on the geometry", "lr": "Adam step on the latents",
        "variance_weight": "lambda of the specular variance penalty",
        "smoothness_weight": "weight of the mesh-color smoothness prior",
        "edge_erosion": "pixels dropped inside each mask's outline when fitting",
        "robust": "Charbonnier scale of the fitting loss (0: squared error)",
        "geometry": "a reconstructed mesh in the capture's frame (default: the true geometry)"}


def add_arguments(parser) -> None:
    for f in fields(MaterialBench):
        parser.add_argument("--" + f.name.replace("_", "-"), type=type(f.default), default=f.default,
                            help=HELP.get(f.name, f.name.replace("_", " ")) + " (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "bench-material")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    _material_table.add_arguments(parser)


def run(args) -> int:
    spec = MaterialBench(**{f.name: getattr(args, f.name) for f in fields(MaterialBench)})
    if args.table:
        return _material_table.run(args, spec)
    emit = Emitter()
    variant.choose(args.variant, emit)
    report = benchmark(spec, Path(args.out), emit)
    m = report["metrics"]
    _records.write_record(
        "material", title="Material on given geometry", variant=variant.choose(args.variant),
        context="the staged material fitted on " + ("a given reconstruction" if spec.geometry else "the true dragon")
                + f", {spec.views} views; scored against the truth rendered the same way",
        rows=[{"figure": "held-out PSNR dB", "value": round(m["held_out_psnr"], 2), "target": "≥ 32"},
              {"figure": "albedo RMSE", "value": round(m["albedo_rmse"], 3), "target": "≤ 0.05"},
              {"figure": "relit PSNR dB", "value": round(m["relit_psnr"], 2), "target": "≥ 30"}])
    emit("done", result="run/result.glb", report="run/report.json", metrics=report["metrics"])
    return 0


def synthetic_capture(spec: MaterialBench, out: Path, emit):
    """The benchmark's capture (synthesised on first use)."""
    folder = out / "capture"
    if not (folder / "capture.json").is_file():
        synth = SynthSpec(mesh=spec.mesh, up=spec.up, views=spec.views, resolution=spec.resolution,
                          lighting="points", albedo="pattern", specular=0.25, roughness=0.35,
                          spp=spec.truth_spp, max_depth=spec.max_depth, held_out=spec.held_out, seed=spec.seed)
        with fsio.atomic_dir(folder, replace=True) as tmp:
            synthesize(synth, tmp, emit)
    return load_capture(folder)


def _views(capture):
    images = [read_linear_rgb(f.image) for f in capture.frames]
    masks = [read_mask(f.mask) for f in capture.frames]
    return images, masks


def _renders(mesh, field, view_set, spp: int, max_depth: int, seed: int = 900) -> list[np.ndarray]:
    env = view_set.environment
    pixels = read_rgba(env.path)[0][..., :3] if env else None
    renderer = SceneRenderer(mesh, field, [f.camera for f in view_set.frames],
                             [f.lights for f in view_set.frames], env,
                             RenderSettings(spp=spp, max_depth=max_depth, integrator="path"), env_pixels=pixels)
    return [renderer.render_numpy(v, seed=seed + v) for v in range(len(view_set.frames))]


def benchmark(spec: MaterialBench, out: Path, emit) -> dict:
    start = time.time()
    capture = synthetic_capture(spec, out, emit)
    truth = load_mesh(capture.path(capture.ground_truth["mesh"]))
    mesh = load_mesh(spec.geometry) if spec.geometry else truth.copy()
    images, masks = _views(capture)
    env = capture.environment
    pixels = read_rgba(env.path)[0][..., :3] if env else None
    material = MeshColorMaterial(mesh, spec.mesh_color_resolution)
    renderer = SceneRenderer(mesh, material.field, [f.camera for f in capture.frames],
                             [f.lights for f in capture.frames], env,
                             RenderSettings(spp=spec.spp, max_depth=spec.max_depth, integrator="prb"),
                             env_pixels=pixels)
    stage_log = []

    def settings(iterations, **kw):
        return stages.FitSettings(iterations=iterations, lr=spec.lr, seed=spec.seed,
                                  smoothness_weight=spec.smoothness_weight, edge_erosion=spec.edge_erosion, robust=spec.robust, **kw)

    emit("stage", stage="material:constant", level=0, faces=mesh.n_faces)
    stage_log.append(stages.fit_constants(renderer, images, masks, material, settings(spec.constant_iterations), emit))
    emit("stage", stage="material:diffuse", level=0, faces=mesh.n_faces)
    stage_log.append(stages.fit_diffuse(renderer, images, masks, material, settings(spec.diffuse_iterations),
                                        light=env is not None, emit=emit))
    emit("stage", stage="material:specular", level=0, faces=mesh.n_faces)
    stage_log.append(stages.fit_specular(renderer, images, masks, material,
                                         settings(spec.specular_iterations, variance_weight=spec.variance_weight),
                                         emit=emit))
    fit_seconds = time.time() - start

    metrics = {}
    display = material.display(mesh)
    pred, gt = corresponding_albedo(display, truth, 100_000, spec.seed)
    metrics["albedo_rmse"] = albedo_rmse(pred, gt)
    truth_field = VertexField(truth.faces, truth.vertex_colors, truth.attributes["specular"],
                              truth.attributes["roughness"])
    for key in ("held_out", "relit"):
        view_set = load_capture(capture.path(capture.ground_truth[key]))
        rendered = _renders(mesh, material.field, view_set, spec.eval_spp, spec.max_depth)
        view_masks = [read_mask(f.mask) for f in view_set.frames]  # the references are rendered here
        targets = _renders(truth, truth_field, view_set, spec.eval_spp, spec.max_depth, seed=500)
        scores = image_metrics(rendered, targets, view_masks)
        metrics[f"{key}_psnr"], metrics[f"{key}_ssim"] = scores["psnr"], scores["ssim"]
    run = out / "run"
    write_glb(run / "result.glb", mesh, material)
    save_mesh(run / "display.ply", display)
    material.save(run / "material.npz")
    report = {"spec": asdict(spec), "geometry": "reconstruction" if spec.geometry else "truth",
              "metrics": metrics, "material": material.summary(),
              "stages": [{"stage": r.stage, "iterations": len(r.losses), "first_loss": r.losses[0],
                          "last_loss": r.loss, "seconds": round(r.seconds, 1),
                          "highlight_share": r.highlight_share, "light_factor": r.light_factor}
                         for r in stage_log],
              "seconds": {"fit": round(fit_seconds, 1), "total": round(time.time() - start, 1)},
              "targets": {"held_out_psnr": 32.0, "albedo_rmse": 0.05, "relit_psnr": 30.0}}
    fsio.write_json(run / "report.json", report)
    return report
