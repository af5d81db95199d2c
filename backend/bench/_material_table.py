"""``bench material --table``: the paper's Table 1 from full geometry + material runs.

For each mesh (``--meshes``; dragon, armadillo, happy Buddha from ``../shared/data/meshes``)
a paper-style capture is synthesised once into ``OUT/<mesh>/capture`` (``--views`` cameras at
``--resolution`` px, two point lights per camera, the procedural albedo pattern, specular
0.25, roughness 0.35, held-out and relit views), then ``reconstruct --init carve --material
staged`` runs in a child process within a wall-clock budget (``--minutes`` for the dragon,
``--other-minutes`` for the others) into ``OUT/<mesh>/run`` (kept and reused unless
``--rerun``). Its wall and CPU seconds and the load average during the run are recorded.

Rows per mesh: ``initialisation`` (the carved mesh with the neutral grey material the run
starts from) and ``reconstruction`` (the run's final mesh rendered with its mesh colors, as
the run fitted them; geometry scores use ``result.ply``, the same mesh). Columns:
Chamfer-L1 and F1@0.01 (100k samples, fractions of the truth's longest side), PSNR / SSIM
of the full render and of its diffuse-only and specular-only passes (backend.render.passes)
at the held-out views under their point lights, against the truth rendered the same way;
for the reconstruction also albedo RMSE, PSNR under the relit sky (never seen by the run),
and the full PSNR its geometry reaches with the true material sampled into the same mesh
colors (a geometry-only bound: what a perfect material fit would score on that mesh).
Writes ``OUT/table1.json`` (rows of meshes not run again are kept when the spec is the same)
and prints the table."""

from __future__ import annotations

import json
import os
import threading
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np

from .. import fsio, variant
from ..capture.images import read_mask, read_rgba
from ..capture.load import load_capture
from ..errors import InputError
from ..geometry.init import initial_mesh
from ..geometry.mesh import Mesh, load_mesh, save_mesh
from ..geometry.topology import keep_largest_components
from ..material.model import MeshColorMaterial
from ..material.transfer import locate
from ..metrics.geometry import corresponding_albedo, geometry_metrics
from ..metrics.image import albedo_rmse, image_metrics
from ..optimize.run_folder import RunFolder
from ..render.fields import VertexField
from ..render.passes import component_renders
from ..render.views import display_field
from ..synth.capture import SynthSpec, synthesize
from . import _launch, _records
from ._data import SHARED_DATA

REPO = Path(__file__).resolve().parents[2]
MESHES_DIR = SHARED_DATA / "meshes"
MESHES = {  # name: (file, up axis)
    "dragon": ("shapefromtracing/dragon.obj", "y"),
    "armadillo": ("stanford/armadillo_86k.obj", "y"),
    "buddha": ("stanford/happy_buddha_vrip_res3.ply", "y"),
}
TARGETS = {"held_out_psnr": 32.0, "albedo_rmse": 0.05, "relit_psnr": 30.0, "dragon_minutes": 20.0}


def add_arguments(parser) -> None:
    g = parser.add_argument_group("Table 1 (--table): full geometry + material runs")
    g.add_argument("--table", action="store_true",
                   help="reconstruct geometry and material from a carved start and print the paper's Table 1")
    g.add_argument("--meshes", default=",".join(MESHES), help="meshes for the table (default: %(default)s)")
    g.add_argument("--minutes", type=float, default=20.0, help="wall-clock budget of the dragon run (default: 20)")
    g.add_argument("--other-minutes", type=float, default=10.0,
                   help="wall-clock budget of the other meshes' runs (default: 10)")
    g.add_argument("--effects", default="specular",
                   help="--effects of the runs (default: direct light with the specular lobe)")
    g.add_argument("--reconstruct-args", default="--preset balanced",
                   help="extra reconstruct options (default: '%(default)s': without a preset, a time budget picks "
                        "the calibrated preset that fits it, Draft for 20 min, which stops long before the budget)")
    g.add_argument("--rerun", action="store_true", help="run again even when OUT/<mesh>/run has a result")


def _log(message: str) -> None:
    print(message, flush=True)


def capture_for(name: str, spec, out: Path, emit):
    """The mesh's synthetic capture (synthesised on first use, or when the spec changed)."""
    rel, up = MESHES[name]
    source = MESHES_DIR / rel
    if not source.is_file():
        raise InputError(source, "benchmark mesh not found", "check ../shared/data/meshes (see its SOURCES.md)")
    folder = out / name / "capture"
    mesh_file = source
    if name == "buddha":  # the vrip scan carries ~1900 tiny floaters: keep the statue itself
        mesh_file = out / name / "mesh.ply"
        if not mesh_file.is_file():
            save_mesh(mesh_file, keep_largest_components(load_mesh(source)))
    synth = SynthSpec(mesh=str(mesh_file), up=up, views=spec.views, resolution=spec.resolution,
                      lighting="points", albedo="pattern", specular=0.25, roughness=0.35, spp=spec.truth_spp,
                      max_depth=spec.max_depth, held_out=spec.held_out, seed=spec.seed)
    if (folder / "capture.json").is_file():
        capture = load_capture(folder)
        if capture.provenance.get("spec") == json.loads(json.dumps(asdict(synth))):
            return capture
    _log(f"[{name}] synthesising {spec.views} views at {spec.resolution} px into {folder}")
    with fsio.atomic_dir(folder, replace=True) as tmp:
        synthesize(synth, tmp, emit)
    return load_capture(folder)


class LoadSampler:
    """The 1-minute load average, sampled every ``every`` seconds in a thread."""

    def __init__(self, every: float = 10.0):
        self.every, self.samples = every, []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.is_set():
            self.samples.append(os.getloadavg()[0])
            self._stop.wait(self.every)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def summary(self) -> dict:
        s = self.samples or [os.getloadavg()[0]]
        return {"mean": round(float(np.mean(s)), 2), "max": round(float(np.max(s)), 2), "samples": len(s)}


def reconstruct(capture_dir: Path, run: Path, minutes: float, args) -> dict:
    """Run ``reconstruct`` in a child process (same niceness as this one); returns the timing."""
    cmd = _launch.backend("reconstruct", capture_dir, "--out", run, "--overwrite", "--init", "carve",
                          "--max-size", args.resolution, "--material", "staged", "--effects", args.effects,
                          "--time-budget", minutes, *args.reconstruct_args.split())
    run.mkdir(parents=True, exist_ok=True)
    with LoadSampler() as load:
        child = _launch.run(cmd, log=run.parent / "reconstruct.log")
    if child.rc != 0:
        raise RuntimeError(f"reconstruct failed ({child.rc}); see {run.parent / 'reconstruct.log'}")
    timing = {"command": cmd[1:], "budget_minutes": minutes, "wall_s": round(child.seconds, 1),
              "cpu_s": round(child.cpu_seconds, 1),
              "load_average_1min": load.summary(), "niceness": os.nice(0), "cores": os.cpu_count()}
    (run / "bench_timing.json").write_text(json.dumps(timing, indent=2))
    return timing


def _scores(rendered: dict, truth: dict, masks) -> dict:
    out = {}
    for comp, images in rendered.items():
        s = image_metrics(images, truth[comp], masks)
        out[comp] = {"psnr": round(s["psnr"], 3), "ssim": round(s["ssim"], 4)}
    return out


def evaluate(name: str, capture, run: Path, spec) -> dict:
    """Table rows for one mesh: initialisation and reconstruction."""
    report = json.loads((run / "report.json").read_text())
    truth = load_mesh(capture.path(capture.ground_truth["mesh"]))
    truth_field = VertexField(truth.faces, truth.vertex_colors, truth.attributes["specular"],
                              truth.attributes["roughness"])
    init = _initial_mesh(capture, run, report["settings"])
    result = load_mesh(run / "result.ply")
    snapshot = json.loads((run / "snapshot.json").read_text())
    display = load_mesh(run / snapshot["mesh"])
    held = load_capture(capture.path(capture.ground_truth["held_out"]))
    relit = load_capture(capture.path(capture.ground_truth["relit"]))
    masks = [read_mask(f.mask) for f in held.frames]
    relit_pixels = read_rgba(relit.environment.path)[0][..., :3]
    kw = dict(spp=spec.eval_spp, max_depth=spec.max_depth)
    reference = component_renders(truth, truth_field, held.frames, **kw)
    relit_ref = component_renders(truth, truth_field, relit.frames, relit.environment, components=("full",),
                                  env_pixels=relit_pixels, seed=500, **kw)["full"]
    state, material_file = RunFolder(run).load_state()
    fitted = MeshColorMaterial.load(material_file)  # rendered on the run's own mesh, as it was fitted
    rows = {}
    for row, mesh, field in (("initialisation", init, display_field(init)),
                             ("reconstruction", Mesh(state["vertices"], state["faces"]), fitted.field)):
        geo = geometry_metrics(mesh if row == "initialisation" else result, truth)
        rendered = component_renders(mesh, field, held.frames, **kw)
        relit_img = component_renders(mesh, field, relit.frames, relit.environment, components=("full",),
                                      env_pixels=relit_pixels, **kw)["full"]
        entry = {"faces": (mesh if row == "initialisation" else result).n_faces,
                 "chamfer_l1": round(geo["chamfer_l1"], 6), "f1@0.01": round(geo["f1@0.01"], 2),
                 **_scores(rendered, reference, masks),
                 "relit_psnr": round(image_metrics(relit_img, relit_ref, masks)["psnr"], 3)}
        if row == "reconstruction":
            pred, gt = corresponding_albedo(display, truth)
            entry["albedo_rmse"] = round(albedo_rmse(pred, gt), 4)
            oracle = component_renders(mesh, truth_as_mesh_colors(mesh, fitted, truth).field, held.frames,
                                       components=("full",), **kw)["full"]
            entry["true_material_psnr"] = round(image_metrics(oracle, reference["full"], masks)["psnr"], 3)
            if fitted.channels["specular"].kind == "colors":
                entry["specular_mean"] = _specular_mean_scores(mesh, material_file, held, relit, relit_pixels,
                                                               reference["full"], relit_ref, masks, kw)
        rows[row] = entry
    return rows


def _specular_mean_scores(mesh, material_file, held, relit, relit_pixels, reference, relit_ref, masks, kw) -> dict:
    """Held-out and relit PSNR with the fitted specular texture replaced by its per-material
    mean (same geometry and albedo): whether the texture generalises beyond its views."""
    flat = MeshColorMaterial.load(material_file)
    flat.make_constant("specular")
    full = component_renders(mesh, flat.field, held.frames, components=("full",), **kw)["full"]
    lit = component_renders(mesh, flat.field, relit.frames, relit.environment, components=("full",),
                            env_pixels=relit_pixels, **kw)["full"]
    return {"full_psnr": round(image_metrics(full, reference, masks)["psnr"], 3),
            "relit_psnr": round(image_metrics(lit, relit_ref, masks)["psnr"], 3)}


def _initial_mesh(capture, run: Path, settings: dict):
    """The run's initial mesh, rebuilt as the run built it (cached beside the run)."""
    path = run.parent / f"init_{Path(str(settings['init'])).stem}_{settings['initial_faces']}.ply"
    if path.is_file() and path.stat().st_mtime >= (run / "report.json").stat().st_mtime:
        return load_mesh(path)
    mesh, _ = initial_mesh(capture, settings["init"], settings["initial_faces"])
    save_mesh(path, mesh)
    return mesh


def truth_as_mesh_colors(mesh, fitted, truth):
    """A mesh-colors material laid out like ``fitted`` with every channel set to the truth's
    material at the samples' closest truth surface points: what the reconstructed geometry
    scores with a perfect material of the same resolution (a geometry-only bound)."""
    oracle = MeshColorMaterial(mesh, fitted.resolution, fitted.labels, fitted.n_materials)
    face, bary, _ = locate(oracle.layout.sample_positions(mesh.vertices), truth.vertices, truth.faces,
                           exhaustive=False)
    corners = truth.faces[face]
    for name, values in (("albedo", truth.vertex_colors), ("specular", truth.attributes["specular"]),
                         ("roughness", truth.attributes["roughness"])):
        values = np.asarray(values, np.float64).reshape(len(truth.vertices), -1)
        oracle.set_values(name, (values[corners] * bary[..., None]).sum(1), "colors")
    return oracle


def format_table(results: dict) -> str:
    head = (f"{'mesh':<10} {'row':<15} {'budget':>7} {'Chamfer':>8} {'F1@.01':>7} {'full PSNR/SSIM':>15} "
            f"{'diffuse':>14} {'specular':>14} {'relit':>6} {'albedo':>7} {'true-mat':>8}")
    lines = [head, "-" * len(head)]
    for name, r in results.items():
        for row in ("initialisation", "reconstruction"):
            e = r["rows"][row]
            cells = [f"{e[c]['psnr']:6.2f}/{e[c]['ssim']:.3f}" for c in ("full", "diffuse", "specular")]
            budget = f"{r['timing']['budget_minutes']:.0f} min" if row == "reconstruction" else ""
            albedo = f"{e['albedo_rmse']:.4f}" if "albedo_rmse" in e else ""
            oracle = f"{e['true_material_psnr']:.2f}" if "true_material_psnr" in e else ""
            lines.append(f"{name:<10} {row:<15} {budget:>7} {e['chamfer_l1']:8.5f} {e['f1@0.01']:7.2f} "
                         f"{cells[0]:>15} {cells[1]:>14} {cells[2]:>14} {e['relit_psnr']:6.2f} {albedo:>7} "
                         f"{oracle:>8}")
    return "\n".join(lines)


def record_rows(results: dict) -> list[dict]:
    """Table 1's rows: per mesh its initialisation and its reconstruction."""
    rows = []
    for name, r in results.items():
        for row in ("initialisation", "reconstruction"):
            e = r["rows"][row]
            label = row if row == "initialisation" else f"reconstruction ({r['timing']['budget_minutes']:g} min)"
            rows.append({"mesh": name, "row": label, "Chamfer-L1": round(e["chamfer_l1"], 5),
                         "F1@0.01": round(e["f1@0.01"], 1),
                         **{c: f"{e[c]['psnr']:.2f} / {e[c]['ssim']:.3f}" for c in ("full", "diffuse", "specular")},
                         "relit dB": round(e["relit_psnr"], 2),
                         "albedo RMSE": round(e["albedo_rmse"], 3) if "albedo_rmse" in e else None,
                         "true-material dB": round(e["true_material_psnr"], 2) if "true_material_psnr" in e else None})
    return rows


def run(args, spec) -> int:
    """The table for ``spec`` (a ``material.MaterialBench``) over ``args.meshes``."""
    variant.choose(args.variant)
    names = [n.strip() for n in args.meshes.split(",") if n.strip()]
    unknown = [n for n in names if n not in MESHES]
    if unknown:
        raise InputError(None, f"unknown mesh(es) {', '.join(unknown)}", f"choose from {', '.join(MESHES)}")
    out = Path(args.out)
    table = out / "table1.json"
    spec_json = {f.name: getattr(spec, f.name) for f in fields(spec)}
    results = {name: rows for name, rows in _earlier(table, spec_json).items() if name not in names}
    for name in names:
        capture = capture_for(name, spec, out, lambda *a, **k: None)
        run_dir = out / name / "run"
        minutes = args.minutes if name == "dragon" else args.other_minutes
        timing_file = run_dir / "bench_timing.json"
        if args.rerun or not (run_dir / "report.json").is_file() or not timing_file.is_file():
            _log(f"[{name}] reconstruct, {minutes:g} min wall-clock budget -> {run_dir}")
            timing = reconstruct(capture.root, run_dir, minutes, args)
        else:
            timing = json.loads(timing_file.read_text())
            _log(f"[{name}] reusing {run_dir} (--rerun to run again)")
        _log(f"[{name}] {timing['wall_s']:.0f} s wall, {timing['cpu_s']:.0f} s CPU, "
             f"load average {timing['load_average_1min']['mean']} (max {timing['load_average_1min']['max']})")
        rows = evaluate(name, capture, run_dir, spec)
        report = json.loads((run_dir / "report.json").read_text())
        results[name] = {"rows": rows, "timing": timing, "run_seconds": report["timings"]["total"],
                         "levels": len(report["levels"]), "material_schedule": report.get("material_schedule"),
                         "effects": report.get("effects", [])[-1:]}
        rec = rows["reconstruction"]
        results[name]["targets"] = {"held_out_psnr>=32": rec["full"]["psnr"] >= 32.0,
                                    "albedo_rmse<=0.05": rec["albedo_rmse"] <= 0.05,
                                    "relit_psnr>=30": rec["relit_psnr"] >= 30.0}
        _log(format_table({name: results[name]}))
        fsio.write_json(table, {"spec": spec_json, "targets": TARGETS, "meshes": results})
    _log("\n" + format_table(results))
    _records.write_record(
        "table1", title="Table 1: shape and material", variant=variant.choose(args.variant),
        context="32 views x 2 point lights at 128 px, a textured glossy truth; reconstruct from carving, staged "
                f"material, {args.minutes:g} min (dragon) or {args.other_minutes:g}; PSNR dB / SSIM of 4 held-out views "
                "and their diffuse and specular passes",
        rows=record_rows(results))
    _log(f"results: {table}")
    return 0


def _earlier(table: Path, spec: dict) -> dict:
    """Rows of meshes a previous run of the same spec wrote to ``table`` (kept when only some
    meshes run again)."""
    try:
        earlier = json.loads(table.read_text())
    except (OSError, ValueError):
        return {}
    return earlier.get("meshes", {}) if earlier.get("spec") == spec else {}
