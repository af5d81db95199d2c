"""The pipeline cases: ``reconstruct`` on a hard capture, recording and checking every step."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ... import variant
from ...capture.load import load_capture
from ...errors import InputError
from ...events import Emitter
from ...geometry.mesh import load_mesh, save_mesh
from ...geometry.topology import inspect
from ...optimize.config import ReconstructConfig
from ...optimize.run import reconstruct as run_reconstruction
from ...optimize.run_folder import RunFolder
from .checks import read_events, recorder, run_folder_problems
from .results import KNOWN, Result, StepLog
from .scenes import (Scene, degenerate_init, grazing_scene, lit_blob, masked_out_scene, meshcolors, near_black_scene,
                     nonfinite_pixel_scene, size_of, sphere_init, sun_scene, swallowing_init, tangled_init, torus_init)


# -- pipeline cases -------------------------------------------------------------------------------------
@dataclass
class Setup:
    """One hard case: its capture, the run's settings and what it must do."""

    about: str
    scene: Callable[[bool], Scene]
    settings: dict = field(default_factory=dict)  # ReconstructConfig overrides
    init: Callable[[bool], object] | None = None  # an initial mesh (given as a file); else --init sphere
    material: Callable[[object], object] | None = None  # material model on the initial mesh
    expect_error: str | None = None  # the run must stop with an InputError containing this
    expect_caught: bool = False  # the loop must skip some steps
    inject_nan: frozenset = frozenset()  # steps whose gradient gets a NaN
    track_tangles: bool = False


def config(quick: bool, **overrides):
    """Tiny (quick) or longer run settings; sphere start, known material, no re-meshing."""
    values = dict(max_size=size_of(quick), coarse_size=size_of(quick), initial_faces=500 if quick else 2000,
                  spp=4 if quick else 8, sppp=2 if quick else 4, iterations=12 if quick else 120,
                  validation_views=2, validation_spp=4, eval_every=4 if quick else 10, max_levels=2 if quick else 3,
                  material_warmup=2 if quick else 20, min_level_iterations=4 if quick else 20,
                  level_iterations=8 if quick else 50, snapshot_every_s=2.0, material=KNOWN, init="sphere",
                  remesh="never")
    values.update(overrides)
    return ReconstructConfig(**values)


def material_case(about, albedo: float, specular: float, roughness: float, estimate: bool) -> Setup:
    known = f"known:{albedo},{albedo},{albedo}:{specular}:{roughness}"
    return Setup(about, lambda q: lit_blob(q, albedo=albedo, specular=specular, roughness=roughness),
                 {"material": "auto" if estimate else known})


def pipeline_cases(quick: bool) -> dict[str, Setup]:
    big = 50_000 if quick else 500_000
    return {
        "roughness_0": material_case("mirror-like truth and known material (roughness 0)", 0.6, 0.9, 0.0, False),
        "roughness_1": material_case("roughness 1 truth and known material", 0.6, 0.5, 1.0, False),
        "specular_0": material_case("specular 0 truth, material estimated", 0.6, 0.0, 0.3, True),
        "specular_1": material_case("specular 1 truth, material estimated", 0.3, 1.0, 0.05, True),
        "grazing_views": Setup("a flat disc seen only 2-6 degrees above its plane", grazing_scene),
        "single_view": Setup("one view", lambda q: lit_blob(q, views=1)),
        "masked_out_views": Setup("two views looking away, one with the object masked out", masked_out_scene),
        "near_black_frames": Setup("frames at 1e-4 exposure; material estimated", near_black_scene,
                                   {"material": "auto"}),
        "nonfinite_pixels": Setup("a frame with NaN and Inf pixels", nonfinite_pixel_scene,
                                  expect_error="NaN or Inf"),
        "sun_1e5": Setup("a 1e5 sun beside a 0.02 sky, glossy, material estimated", sun_scene,
                         {"material": "auto", "integrator": "prb_projective"}),
        "degenerate_init": Setup("initial mesh with degenerate, flipped, duplicate and non-manifold parts",
                                 lit_blob, init=degenerate_init),
        "oversized_init": Setup("initial mesh overfilling every frame", lit_blob, init=sphere_init(1.4)),
        "oversized_step": Setup("overfilling initial mesh with a 100x step: steps that swallow a camera",
                                lit_blob, {"step": 10.0, "level_iterations": 30 if quick else 60,
                                           "iterations": 30 if quick else 120, "max_levels": 1},
                                init=sphere_init(1.4), expect_caught=True),
        "camera_inside_init": Setup("initial mesh enclosing a camera", lit_blob, init=swallowing_init,
                                    expect_error="encloses 1 of the 6 cameras"),
        "spp_1": Setup("1 sample per pixel everywhere", lit_blob, {"spp": 1, "sppp": 1, "validation_spp": 1}),
        "self_intersecting_init": Setup("a self-intersecting mesh from an oversized step, then re-meshed",
                                        lit_blob, {"remesh": "always"}, init=tangled_init, track_tangles=True),
        "lr_100x": Setup("vertex and material steps 100x too large" + ("" if quick else ", re-meshing"), lit_blob,
                         {"step": 10.0, "material_lr": 3.0, "material": "auto",
                          "remesh": "never" if quick else "always"}, track_tangles=True),
        "meshcolors_r0": Setup("mesh colors, r = 0 (one value per face)", lit_blob, {"initial_faces": 5120},
                               init=sphere_init(0.7), material=meshcolors(0)),
        "meshcolors_r8": Setup("mesh colors, r = 8", lit_blob, {"initial_faces": 5120}, init=sphere_init(0.7),
                               material=meshcolors(8)),
        "nan_gradient": Setup("NaN gradients injected at steps 1, 4 and 5", lit_blob,
                              inject_nan=frozenset({1, 4, 5}), expect_caught=True),
        f"faces_{big // 1000}k": Setup(f"a {big // 1000}k-face initial mesh", lit_blob,
                                       {"initial_faces": big, "max_faces": 4 * big, "max_levels": 1,
                                        "iterations": 3 if quick else 10}, init=torus_init(big)),
    }


def reconstruct(capture_dir: Path, run_dir: Path, settings, material=None, **record):
    """Run the reconstruction loop in this process as the command does, recording every step.
    Returns (exit code or the InputError raised, StepLog)."""
    variant.choose()
    folder = RunFolder.create(run_dir, resume=False, overwrite=False)
    emit = Emitter(log_path=folder.events, quiet=True)
    log, objective = recorder(**record)
    try:
        emit("start", run=str(run_dir), capture=str(capture_dir), settings=dataclasses.asdict(settings))
        outcome = run_reconstruction(load_capture(capture_dir), folder, settings, emit, material=material,
                                     objective_factory=objective).exit_code
    except InputError as err:
        emit("error", message=err.line())
        outcome = err
    finally:
        emit.close()
    return outcome, log


def judge(result: Result, log: StepLog, run: Path, outcome, setup: Setup) -> None:
    """The assertions every pipeline case shares."""
    result.steps = len(log.losses)
    result.notes["max_grad_norm"] = max((g for g in log.grad_norms if math.isfinite(g)), default=None)
    if setup.expect_error is not None:
        result.check(isinstance(outcome, InputError) and setup.expect_error in str(outcome),
                     f"expected an input error about '{setup.expect_error}', got {outcome!r}")
        result.notes["error"] = str(outcome)
        result.check(not (run / "report.json").exists(), "report written despite the error")
        result.problems += run_folder_problems(run)
        return
    if not result.check(outcome == 0, f"run ended with {outcome!r}"):
        return
    result.check(result.steps > 0, "no optimisation step ran")
    result.problems += log.problems
    report = json.loads((run / "report.json").read_text())
    result.caught = int(report["skipped_steps"])
    result.final_loss = report["losses"][-1] if report["losses"] else None
    result.check(report["result"]["iterations"] == result.steps,
                 f"report says {report['result']['iterations']} steps, {result.steps} ran")
    # every non-finite step was skipped, counted in the report and announced
    result.check(result.caught >= log.nonfinite_steps,
                 f"{log.nonfinite_steps} non-finite steps but only {result.caught} skipped")
    warnings = [e["message"] for e in read_events(run)
                if e["event"] == "warning" and e["message"].startswith("step ") and " skipped: " in e["message"]]
    result.check(len(warnings) == result.caught, f"{len(warnings)} skip warnings for {result.caught} skipped steps")
    if setup.inject_nan:
        result.check(log.nonfinite_steps == len(setup.inject_nan) == result.caught,
                     f"{len(setup.inject_nan)} NaN gradients injected, {result.caught} skipped")
    if setup.expect_caught:
        result.check(result.caught > 0, "expected skipped steps, none occurred")
    if warnings:
        result.notes["skipped"] = sorted({w.split(" skipped: ")[1].split(" (")[0] for w in warnings})
    others = [e["message"] for e in read_events(run) if e["event"] == "warning" and e["message"] not in warnings]
    if others:
        result.notes["warnings"] = others
    result.check(result.final_loss is not None and math.isfinite(result.final_loss), f"final loss {result.final_loss}")
    losses = [e["loss"] for e in read_events(run) if e["event"] == "progress" and e.get("loss") is not None]
    result.check(all(math.isfinite(x) for x in losses), "non-finite loss in the progress events")
    result.check(all(math.isfinite(x) for x in log.validation), "non-finite validation loss")
    # each level's starting mesh; after a transition a closed manifold, after a re-mesh untangled
    remeshed = [level.get("remesh", {}).get("applied", False) for level in report["levels"]]
    for level, checks in enumerate(log.level_meshes):
        result.check(checks["finite"], f"level {level} mesh has non-finite vertices")
        if level > 0:
            result.check(checks["manifold"], f"level {level} mesh not a closed manifold: {checks['issues']}")
            if remeshed[level - 1]:
                result.check(checks["self_intersections"] == 0,
                             f"re-meshed level {level} has {checks['self_intersections']} self-intersecting faces")
    result.notes["self_intersecting_faces"] = [c["self_intersections"] for c in log.level_meshes]
    if log.step_intersections:
        result.notes["most_self_intersecting_faces_during_steps"] = max(log.step_intersections)
    result.notes["remeshed"] = remeshed
    mesh = load_mesh(run / "result.ply")
    result.check(bool(np.all(np.isfinite(mesh.vertices))), "result.ply has non-finite vertices")
    result.check(not remeshed or not remeshed[-1] or inspect(mesh).closed_manifold, "result not a closed manifold")
    result.problems += run_folder_problems(run)


def run_pipeline_case(name: str, setup: Setup, work: Path, quick: bool) -> Result:
    variant.choose()
    start = time.perf_counter()
    result = Result(name, notes={"about": setup.about})
    work = Path(work)
    capture = setup.scene(quick).write(work / "capture")
    overrides = dict(setup.settings)
    initial = None
    if setup.init is not None:
        initial = setup.init(quick)
        save_mesh(work / "init.ply", initial)
        overrides["init"] = str(work / "init.ply")
    material = setup.material(initial) if setup.material is not None else None
    outcome, log = reconstruct(capture, work / "run", config(quick, **overrides), material,
                               inject_nan=setup.inject_nan, track_tangles=setup.track_tangles)
    judge(result, log, work / "run", outcome, setup)
    result.seconds = round(time.perf_counter() - start, 1)
    return result
