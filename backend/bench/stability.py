"""Hard cases through the real reconstruction pipeline: every step finite and valid (table of cases).

``python -m backend bench stability [--quick] [--case NAME ...]`` runs ``reconstruct`` on
small synthetic captures that each have one hard property: extreme materials (roughness and
specular reflectance near 0 and 1), grazing or single views, views with the object masked
out, near-black frames, frames with NaN/Inf pixels, a 1e5 sun beside a dim sky, degenerate,
oversized or camera-enclosing initial meshes, 1 spp, a learning rate 100x too large (vertex
and material steps), mesh colors at r = 0 and 8, a mesh of 50k (``--quick``) or 500k faces,
an injected NaN gradient, a backend killed mid-write and resumed, a full disk. It also
checks the projective geometry gradient and the mesh-colors gradient against central finite
differences.

For each pipeline case every gradient evaluation is recorded (the loop's ``Objective`` is
wrapped, the real one does the work) and checked: loss, gradients, vertex positions and
material latents finite, material values in their ranges; every non-finite step skipped,
counted in report.json and announced by a warning; each level's mesh finite and, after
refinement, a closed manifold, and free of self-intersections after a re-mesh; the outputs
(result.ply, last snapshot) valid; no crash. ``--quick`` runs the tiny versions the tests
use (32 px, about a dozen steps, in this process); the default runs the longer versions,
each in its own process so that its peak memory is measured (the 500k-face case must stay
under 12 GB). Prints a table: case, steps run, non-finite or invalid steps caught, final
loss, peak memory, pass/fail; writes ``OUT/results.json``."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parents[2]
MEMORY_LIMIT_GB = 12.0
GRADIENT_TOLERANCE = 0.05  # relative error of AD against central finite differences
KNOWN = "known:0.6,0.6,0.6:0.2:0.4"


# -- results ------------------------------------------------------------------------------------------
@dataclass
class Result:
    """What one case did and whether it held up."""

    case: str
    steps: int = 0  # optimisation steps run (gradient evaluations)
    caught: int = 0  # steps the loop skipped (non-finite values, invalid geometry), from report.json
    final_loss: float | None = None
    peak_rss_gb: float | None = None
    seconds: float = 0.0
    problems: list[str] = field(default_factory=list)
    notes: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return not self.problems

    def check(self, condition: bool, problem: str) -> bool:
        if not condition:
            self.problems.append(problem)
        return bool(condition)

    def to_json(self) -> dict:
        return {**dataclasses.asdict(self), "passed": self.passed}


@dataclass
class StepLog:
    """Every gradient evaluation of a run, recorded by :func:`recording`."""

    losses: list[float] = field(default_factory=list)
    grad_norms: list[float] = field(default_factory=list)
    nonfinite_steps: int = 0  # evaluations whose loss or gradients were not finite (injected included)
    problems: list[str] = field(default_factory=list)  # non-finite inputs, material values out of range
    validation: list[float] = field(default_factory=list)
    level_meshes: list[dict] = field(default_factory=list)  # checks of each level's starting mesh
    step_intersections: list[int] = field(default_factory=list)  # self-intersecting faces at each step

    def flag(self, problem: str) -> None:
        if len(self.problems) < 5:
            self.problems.append(problem)


# -- checks -------------------------------------------------------------------------------------------
def material_problems(material) -> list[str]:
    """Non-finite latents, or values (float32 sigmoid of the latents, as the BSDF computes
    them) outside the channel's range."""
    from ..optimize.material import CHANNELS

    channels = getattr(material, "CHANNELS", CHANNELS)
    problems = []
    for name, latent in material.parameters().items():
        z = np.asarray(latent, np.float32)
        _, lo, hi = channels[name]
        with np.errstate(over="ignore"):
            v = lo + (hi - lo) / (1 + np.exp(-z))
        if not np.all(np.isfinite(z)):
            problems.append(f"material latent '{name}' not finite")
        elif not (np.all(np.isfinite(v)) and v.min(initial=lo) >= lo and v.max(initial=hi) <= hi):
            problems.append(f"material '{name}' outside [{lo}, {hi}]")
    return problems


def self_intersections(mesh) -> int:
    """Faces that intersect another face of the mesh (pymeshlab)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    return int(ms.current_mesh().selected_face_number())


def mesh_checks(mesh) -> dict:
    from ..geometry.topology import inspect

    report = inspect(mesh)
    return {"faces": mesh.n_faces, "finite": bool(np.all(np.isfinite(mesh.vertices))),
            "manifold": report.closed_manifold, "issues": report.issues,
            "self_intersections": self_intersections(mesh)}


@contextlib.contextmanager
def recording(inject_nan: set[int] = frozenset(), track_tangles: bool = False):
    """Record every gradient evaluation of the reconstruction loops started inside.

    The loop builds one ``Objective`` per level; this swaps in a subclass that checks the
    level's starting mesh, every step's inputs (vertices, material latents and values) and
    outputs (loss, gradients), and otherwise defers to the real objective. ``inject_nan``:
    step indices whose gradient gets a NaN, as a renderer fault would (the loop must skip
    them); ``track_tangles``: count self-intersecting faces at every step (small meshes)."""
    from ..geometry.mesh import Mesh
    from ..optimize import loop
    from ..optimize.objective import Objective

    log = StepLog()

    class RecordingObjective(Objective):
        def __init__(self, mesh, material, *args, **kwargs):
            log.level_meshes.append(mesh_checks(mesh))
            self.faces = mesh.faces
            super().__init__(mesh, material, *args, **kwargs)

        def loss_and_grad(self, vertices, view_ids, step_seed, geometry=True, material=True):
            step = len(log.losses)
            if not np.all(np.isfinite(vertices)):
                log.flag(f"step {step}: non-finite vertex positions")
            for problem in material_problems(self.material):
                log.flag(f"step {step}: {problem}")
            if track_tangles:
                log.step_intersections.append(self_intersections(Mesh(vertices, self.faces)))
            loss, grad, mgrads = super().loss_and_grad(vertices, view_ids, step_seed, geometry, material)
            if step in inject_nan:
                if grad is not None:
                    grad = grad.copy()
                    grad[len(grad) // 2, 0] = np.nan
                else:
                    mgrads = {name: np.full_like(g, np.nan) for name, g in mgrads.items()}
            grads = ([grad] if grad is not None else []) + list(mgrads.values())
            log.nonfinite_steps += not (math.isfinite(loss) and all(np.all(np.isfinite(g)) for g in grads))
            log.losses.append(loss)
            log.grad_norms.append(float(np.sqrt(sum(np.sum(np.square(g)) for g in grads))) if grads else 0.0)
            return loss, grad, mgrads

        def validation_loss(self, vertices, view_ids, seed, spp=None):
            value = super().validation_loss(vertices, view_ids, seed, spp)
            log.validation.append(value)
            return value

    saved = loop.Objective
    loop.Objective = RecordingObjective
    try:
        yield log
    finally:
        loop.Objective = saved


def read_events(run: Path) -> list[dict]:
    """events.jsonl of a run folder; raises ValueError on a line that is not JSON."""
    path = Path(run) / "events.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


def temporary_files(run: Path) -> list[Path]:
    """Leftovers of atomic writes (fsio's hidden temporary siblings) in a run folder."""
    return [p for p in Path(run).rglob(".*") if ".tmp" in p.name]


def run_folder_problems(run: Path) -> list[str]:
    """Everything in a run folder must be whole: snapshot.json names a loadable mesh of the
    stated size with finite vertices and material in range, the resumable state loads,
    every event line parses and every other file reads (temporary files aside)."""
    from ..geometry.mesh import load_mesh
    from ..material.model import MeshColorMaterial
    from ..optimize.material import ConstantMaterial
    from ..optimize.run_folder import RunFolder

    run = Path(run)
    problems = []
    temporary = set(temporary_files(run))
    try:
        read_events(run)
    except ValueError as err:
        problems.append(f"events.jsonl has a broken line ({err})")
    if (run / "snapshot.json").exists():
        try:
            snap = json.loads((run / "snapshot.json").read_text())
            mesh = load_mesh(run / snap["mesh"])
            # the display mesh splits every face r x r when mesh colors vary (docs/protocol.md)
            split = round(math.sqrt(mesh.n_faces / max(snap["faces"], 1)))
            if split < 1 or mesh.n_faces != snap["faces"] * split * split or not np.all(np.isfinite(mesh.vertices)):
                problems.append(f"snapshot {snap['mesh']}: {mesh.n_faces} faces, {snap['faces']} stated, or not finite")
            values = [mesh.vertex_colors] + [mesh.attributes.get(k) for k in ("specular", "roughness")]
            if any(v is None or not np.all((v >= 0) & (v <= 1)) for v in values):
                problems.append(f"snapshot {snap['mesh']}: material missing or outside [0, 1]")
        except Exception as err:  # any failure to read it back is what this check reports
            problems.append(f"snapshot unreadable: {type(err).__name__}: {err}")
    if (run / "state" / "state.json").exists():
        try:
            state, material = RunFolder(run).load_state()
            (MeshColorMaterial if "resolution" in np.load(material).files else ConstantMaterial).load(material)
            if not np.all(np.isfinite(state["vertices"])):
                problems.append("saved state has non-finite vertices")
        except Exception as err:
            problems.append(f"saved state unreadable: {type(err).__name__}: {err}")
    for path in sorted(p for p in run.rglob("*") if p.is_file() and p not in temporary):
        try:
            if path.suffix == ".ply":
                load_mesh(path)
            elif path.suffix == ".npz":
                dict(np.load(path))
            elif path.suffix == ".json":
                json.loads(path.read_text())
        except Exception as err:
            problems.append(f"{path.relative_to(run)} unreadable: {type(err).__name__}")
    return problems


# -- synthetic captures --------------------------------------------------------------------------------
@dataclass
class Scene:
    """A synthetic capture to build: object, views, lights and material of the truth."""

    mesh: object  # backend.geometry.mesh.Mesh
    cameras: list
    lights: list  # per view: list of PointLight
    albedo: float | list = 0.6
    specular: float = 0.2
    roughness: float = 0.4
    env_pixels: np.ndarray | None = None
    spp: int = 16
    edit: Callable | None = None  # (view index, rgb, alpha) -> (rgb, alpha): post-processing

    def write(self, out: Path) -> Path:
        """Render the capture into ``out`` (images, masks, capture.json; no ground truth, so the
        loop spends no time on metrics)."""
        from .. import variant

        variant.choose()
        from ..capture.format import save_capture
        from ..capture.images import write_image, write_mask
        from ..capture.model import Capture, Environment, Frame
        from ..render.fields import ConstantField
        from ..render.scene import RenderSettings, SceneRenderer

        out = Path(out)
        env = None
        if self.env_pixels is not None:
            env = Environment(out / "env.exr")
            write_image(env.path, self.env_pixels)
        renderer = SceneRenderer(self.mesh, ConstantField(self.albedo, self.specular, self.roughness), self.cameras,
                                 self.lights, env, RenderSettings(spp=self.spp, max_depth=3, integrator="path"),
                                 env_pixels=self.env_pixels, rgba=True)
        frames = []
        for i, cam in enumerate(self.cameras):
            rgba = renderer.render_numpy(i, seed=i)
            rgb, alpha = rgba[..., :3], rgba[..., 3]
            if self.edit is not None:
                rgb, alpha = self.edit(i, rgb, alpha)
            image, mask = out / "images" / f"{i:04d}.exr", out / "masks" / f"{i:04d}.png"
            write_image(image, rgb)
            write_mask(mask, alpha)
            frames.append(Frame(f"{i:04d}", image, cam, mask=mask, lights=self.lights[i]))
        save_capture(Capture(out, frames, env, provenance={"source": "bench stability"}))
        return out


def size_of(quick: bool) -> int:
    return 32 if quick else 64


def orbit(n: int, size: int, radius: float = 0.6):
    from ..synth.layout import fibonacci_sphere, orbit_cameras

    return orbit_cameras(fibonacci_sphere(n), np.zeros(3), radius, size)


def lamp_lights(cameras, power: float = 2.0):
    from ..capture.model import PointLight

    return [[PointLight(c.centre, np.full(3, power))] for c in cameras]


def lit_blob(quick: bool, views: int = 6, **material) -> Scene:
    """The procedural blob (about 1.1 units across) seen from ``views`` cameras around it, a
    lamp at each camera."""
    from ..synth.procedural import blob

    cams = orbit(views, size_of(quick))
    return Scene(blob(3 if quick else 4), cams, lamp_lights(cams), **material)


def grazing_scene(quick: bool) -> Scene:
    """A flat disc seen only from 2 to 6 degrees above its plane."""
    from ..capture.model import Camera
    from ..synth.layout import look_at
    from ..synth.procedural import icosphere

    size = size_of(quick)
    disc = icosphere(3 if quick else 4, 0.6)
    disc.vertices[:, 2] *= 0.12
    f = 0.5 * size / np.tan(np.radians(20))
    cams = []
    for k, az in enumerate(np.linspace(0, 2 * np.pi, 6, endpoint=False)):
        el = np.radians(2 + 4 * (k % 2))
        eye = 2.0 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(Camera(size, size, f, f, size / 2, size / 2, look_at(eye, np.zeros(3))))
    return Scene(disc, cams, lamp_lights(cams))


def masked_out_scene(quick: bool) -> Scene:
    """Six views: two look away from the object (empty frames and masks), one sees it with
    image and mask blanked (the object masked out where it stands)."""
    from ..synth.layout import look_at

    scene = lit_blob(quick)
    for i in (1, 3):
        cam = scene.cameras[i]
        cam.camera_to_world = look_at(cam.centre, 2 * cam.centre)
    scene.edit = lambda i, rgb, alpha: (rgb * 0, alpha * 0) if i == 4 else (rgb, alpha)
    return scene


def near_black_scene(quick: bool) -> Scene:
    """Frames at 1e-4 of the exposure; one of them exactly black (its mask intact)."""
    scene = lit_blob(quick)
    scene.edit = lambda i, rgb, alpha: (rgb * (0.0 if i == 0 else 1e-4), alpha)
    return scene


def nonfinite_pixel_scene(quick: bool) -> Scene:
    """One frame with a NaN and an Inf pixel on the object (a corrupt or clipped HDR frame)."""
    scene = lit_blob(quick)

    def corrupt(i, rgb, alpha):
        if i == 2:
            h, w = alpha.shape
            rgb = rgb.copy()
            rgb[h // 2, w // 2], rgb[h // 2 + 1, w // 2] = np.nan, np.inf
        return rgb, alpha

    scene.edit = corrupt
    return scene


def sun_scene(quick: bool) -> Scene:
    """Lit by an HDR map alone: a 2x2-pixel sun of radiance 1e5 beside a sky of 0.02; glossy."""
    sky = np.full((32, 64, 3), 0.02, np.float32)
    sky[6:8, 20:22] = 1e5
    scene = lit_blob(quick, specular=0.5, roughness=0.1)
    scene.lights = [[] for _ in scene.cameras]
    scene.env_pixels, scene.spp = sky, 4
    return scene


def degenerate_init(quick: bool):
    """A sphere around the object with flipped faces, duplicate vertices, zero-area and sliver
    triangles, a stray triangle through the inside and a non-manifold edge (a fin)."""
    from ..geometry.mesh import Mesh
    from ..synth.procedural import icosphere

    sphere = icosphere(3, 0.7)
    v, f = sphere.vertices, sphere.faces.copy()
    f[::9] = f[::9, ::-1]
    n = len(v)
    a, b = f[0, 0], f[0, 1]
    v = np.vstack([v, v[:3], v[0] + [1e-9, 0, 0], 1.3 * v[a] + [0, 0.05, 0], 1.3 * v[b]])
    extra = [[0, n, 0], [1, 1, 2],  # zero-area (a duplicate vertex) and collapsed
             [n + 1, n + 2, n + 3],  # a stray triangle through the inside
             [0, 1, n + 3],  # a sliver
             [a, b, n + 4], [b, a, n + 5]]  # a fin: third and fourth face on one edge
    return Mesh(v, np.vstack([f, extra]))


def tangled_init(quick: bool):
    """A sphere after an oversized step: a cap of vertices pushed 1.6 radii down through the
    opposite side, so the surface intersects itself."""
    from ..synth.procedural import icosphere

    mesh = icosphere(3, 0.7)
    cap = mesh.vertices[:, 2] > 0.35
    mesh.vertices[cap, 2] -= 1.6 * 0.7
    return mesh


def swallowing_init(quick: bool):
    """A sphere over the object that also swallows the first camera (a mesh in the wrong place
    or units), while the other cameras still see it."""
    from ..synth.procedural import icosphere

    eye = orbit(6, size_of(quick))[0].centre
    mesh = icosphere(3, 0.6 * np.linalg.norm(eye))
    mesh.vertices += 0.5 * eye
    return mesh


def sphere_init(radius: float, subdivisions: int = 3):
    def build(quick: bool):
        from ..synth.procedural import icosphere

        return icosphere(subdivisions, radius)

    return build


def torus_init(faces: int):
    """A torus of about ``faces`` faces around the object."""
    def build(quick: bool):
        from ._scenes import torus

        n_minor = max(8, int(round(np.sqrt(faces / 5))))
        return torus(0.45, 0.25, max(8, int(round(faces / 2 / n_minor))), n_minor)

    return build


def meshcolors(resolution: int):
    """Mesh colors at ``resolution`` on the initial mesh, every channel spatial and estimated."""
    def build(mesh):
        from ..material.model import MeshColorMaterial

        material = MeshColorMaterial(mesh, resolution)
        for name in material.CHANNELS:
            material.make_spatial(name)
        return material

    return build


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
    from ..optimize.config import ReconstructConfig

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
        "near_black_frames": Setup("frames at 1e-4 exposure, one black; material estimated", near_black_scene,
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
    from .. import variant
    from ..capture.load import load_capture
    from ..errors import InputError
    from ..events import Emitter
    from ..optimize.loop import Reconstruction
    from ..optimize.run_folder import RunFolder

    variant.choose()
    folder = RunFolder.create(run_dir, resume=False, overwrite=False)
    emit = Emitter(log_path=folder.events, quiet=True)
    with recording(**record) as log:
        try:
            emit("start", run=str(run_dir), capture=str(capture_dir), settings=dataclasses.asdict(settings))
            outcome = Reconstruction(load_capture(capture_dir), folder, settings, emit, material=material).run()
        except InputError as err:
            emit("error", message=err.line())
            outcome = err
        finally:
            emit.close()
    return outcome, log


def judge(result: Result, log: StepLog, run: Path, outcome, setup: Setup) -> None:
    """The assertions every pipeline case shares."""
    from ..errors import InputError
    from ..geometry.mesh import load_mesh
    from ..geometry.topology import inspect

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
    from .. import variant
    from ..geometry.mesh import save_mesh

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


# -- gradients against finite differences ------------------------------------------------------------------
def _target_views(count: int = 2):
    """The blob at 32 px from ``count`` cameras, each under its own lamp: the loss's targets."""
    from ..optimize.views import View
    from ..render.fields import ConstantField
    from ..render.scene import RenderSettings, SceneRenderer
    from ..synth.procedural import blob

    cams = orbit(count, 32)
    lights = lamp_lights(cams)
    truth = SceneRenderer(blob(3), ConstantField(0.6, 0.2, 0.4), cams, lights, settings=RenderSettings(spp=64),
                          rgba=True)
    views = []
    for i, cam in enumerate(cams):
        rgba = truth.render_numpy(i, seed=i)
        views.append(View(f"{i}", cam, rgba[..., :3], rgba[..., 3], lights[i]))
    return views


def _compare(result: Result, ad: dict[str, float], fd: dict[str, float]) -> None:
    errors = {name: abs(ad[name] - fd[name]) / max(abs(fd[name]), 1e-30) for name in fd}
    result.notes["relative_errors"] = {k: round(v, 4) for k, v in errors.items()}
    result.notes["ad"] = {k: float(f"{v:.6g}") for k, v in ad.items()}
    result.notes["fd"] = {k: float(f"{v:.6g}") for k, v in fd.items()}
    for name, err in errors.items():
        result.check(err <= GRADIENT_TOLERANCE, f"{name}: AD {ad[name]:.5g} vs FD {fd[name]:.5g} ({100 * err:.1f}%)")
    result.steps = len(errors)
    result.final_loss = max(errors.values())


def gradient_geometry(work: Path, quick: bool) -> Result:
    """The loop's projective vertex gradient (two views, each under its own lamp, log-tone
    masked loss) against central finite differences of the same loss along smooth
    displacement fields: translations along x, y, z and a bump along the normals."""
    from .. import variant

    variant.choose()
    from ..optimize.material import ConstantMaterial
    from ..optimize.objective import Objective
    from ..render.scene import RenderSettings
    from ..synth.procedural import icosphere

    start = time.perf_counter()
    result = Result("gradient_geometry")
    mesh = icosphere(3, 0.5)
    spp = 64 if quick else 256
    settings = RenderSettings(spp=spp, integrator="direct_projective", sppc=spp, sppp=spp, sppi=0)
    objective = Objective(mesh, ConstantMaterial.from_spec(KNOWN), _target_views(), settings)
    v0, ids = mesh.vertices, [0, 1]
    normals = v0 / np.linalg.norm(v0, axis=1, keepdims=True)
    fields = {"translate_x": np.tile([1.0, 0, 0], (len(v0), 1)), "translate_y": np.tile([0, 1.0, 0], (len(v0), 1)),
              "translate_z": np.tile([0, 0, 1.0], (len(v0), 1)),
              "bump": normals * (np.sin(6 * v0[:, :1]) * np.cos(4 * v0[:, 1:2]))}
    grad = np.mean([objective.loss_and_grad(v0, ids, 1000 + s)[1] for s in range(8)], axis=0)
    ad = {name: float(np.sum(grad * d)) for name, d in fields.items()}
    h, fd_spp = 0.01, 1024
    fd = {name: float(np.mean([(objective.loss(v0 + h * d, ids, s, fd_spp) - objective.loss(v0 - h * d, ids, s, fd_spp))
                               / (2 * h) for s in range(2)])) for name, d in fields.items()}
    _compare(result, ad, fd)
    result.seconds = round(time.perf_counter() - start, 1)
    return result


def gradient_meshcolors(work: Path, quick: bool) -> Result:
    """The loop's gradient with respect to mesh-color latents (r = 2, every channel spatial,
    random values with a visible highlight; two views, each under its own lamp) against
    central finite differences at 1024 spp along random latent directions, per channel and
    all together."""
    from .. import variant

    variant.choose()
    from ..material.model import MeshColorMaterial
    from ..optimize.objective import Objective
    from ..render.scene import RenderSettings
    from ..synth.procedural import icosphere

    start = time.perf_counter()
    result = Result("gradient_meshcolors")
    mesh = icosphere(2, 0.5)
    material = MeshColorMaterial(mesh, 2)
    rng = np.random.default_rng(1)
    ranges = {"albedo": (0.2, 0.8), "specular": (0.5, 0.9), "roughness": (0.1, 0.4)}  # a visible highlight
    for name, (width, _, _) in material.CHANNELS.items():
        material.make_spatial(name)
        material.set_values(name, rng.uniform(*ranges[name], (material.layout.n_samples, width)), "colors")
    spp = 256
    objective = Objective(mesh, material, _target_views(),
                          RenderSettings(spp=spp, integrator="direct_projective", sppc=spp, sppp=4, sppi=0))
    ids = [0, 1]
    z0 = {name: np.array(z, np.float64) for name, z in material.parameters().items()}
    directions = {name: {name: rng.normal(size=z.shape)} for name, z in z0.items()}
    directions["all"] = {name: rng.normal(size=z.shape) for name, z in z0.items()}
    grads = [objective.loss_and_grad(mesh.vertices, ids, 500 + s, geometry=False)[2] for s in range(4)]
    ad = {key: float(np.mean([sum(np.sum(g[n] * d[n]) for n in d) for g in grads])) for key, d in directions.items()}

    def loss_at(step: dict, seed: int) -> float:
        material.load_parameters({n: z0[n] + step.get(n, 0.0) for n in z0})
        return objective.loss(mesh.vertices, ids, 500 + seed, 1024)

    h = 0.01
    fd = {}
    for key, d in directions.items():
        fd[key] = float(np.mean([(loss_at({n: h * x for n, x in d.items()}, s)
                                  - loss_at({n: -h * x for n, x in d.items()}, s)) / (2 * h) for s in range(2)]))
    material.load_parameters(z0)
    _compare(result, ad, fd)
    result.seconds = round(time.perf_counter() - start, 1)
    return result


# -- process faults ------------------------------------------------------------------------------------------
def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
                PYTHONUNBUFFERED="1")


def _reconstruct_args(capture: Path, run: Path, init: Path, faces: int, iterations: int) -> list[str]:
    return [sys.executable, "-m", "backend", "reconstruct", str(capture), "--out", str(run), "--init", str(init),
            "--initial-faces", str(faces), "--max-size", "32", "--coarse-size", "32", "--spp", "2",
            "--iterations", str(iterations), "--max-levels", "2", "--material", KNOWN, "--remesh", "never"]


def _kill_at_write(args: list[str], run: Path, after_snapshots: int, timeout: float = 300) -> bool:
    """Start the backend and SIGKILL it the moment it starts an atomic write (a new temporary
    file appears in the run folder) once ``after_snapshots`` snapshot events have come. False
    if it ended first."""
    import threading

    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=_env(), cwd=REPO)
    snapshots = []
    reader = threading.Thread(target=lambda: snapshots.extend(line for line in proc.stdout if '"snapshot"' in line),
                              daemon=True)
    reader.start()
    old = set(temporary_files(run)) if run.exists() else set()
    deadline = time.monotonic() + timeout
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            if len(snapshots) >= after_snapshots and run.exists() and set(temporary_files(run)) - old:
                proc.send_signal(signal.SIGKILL)
                return True
            time.sleep(0.0005)
        return False
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        reader.join(timeout=5)


def killed_mid_write(work: Path, quick: bool) -> Result:
    """The backend (``reconstruct`` with a mesh large enough that a snapshot takes a while to
    write) is killed with SIGKILL the moment it starts an atomic write: during its first
    snapshot, during a later one, and after resuming; after each kill every file in the run
    folder is whole (the last snapshot and the saved state load) and the run goes on with
    --resume (or starts over when no state was saved yet). The last resume must finish with
    a valid result."""
    from ..geometry.mesh import load_mesh, save_mesh
    from ..geometry.topology import inspect

    start = time.perf_counter()
    result = Result("killed_mid_write")
    work = Path(work)
    capture = lit_blob(True).write(work / "capture")
    faces = 20_000 if quick else 200_000
    save_mesh(work / "init.ply", torus_init(faces)(quick))
    run = work / "run"
    iterations = 6 if quick else 20
    kills, mid_write, leftovers = 0, 0, 0
    for after_snapshots in (0, 1, 0) if quick else (0, 1, 0, 1, 0, 1):
        resume = (run / "state" / "state.json").exists()
        args = _reconstruct_args(capture, run, work / "init.ply", faces, iterations)
        if not _kill_at_write(args + (["--resume"] if resume else ["--overwrite"]), run, after_snapshots):
            result.notes.setdefault("finished_before_kill", 0)
            result.notes["finished_before_kill"] += 1
            continue
        kills += 1
        mid_write += len(temporary_files(run)) > leftovers  # a write was cut off
        leftovers = len(temporary_files(run))
        for problem in run_folder_problems(run):
            result.problems.append(f"after kill {kills}: {problem}")
    proc = subprocess.run(_reconstruct_args(capture, run, work / "init.ply", faces, iterations)
                          + (["--resume"] if (run / "state" / "state.json").exists() else ["--overwrite"]),
                          capture_output=True, text=True, env=_env(), cwd=REPO, timeout=600)
    result.notes.update(kills=kills, killed_during_a_write=mid_write, temporary_files_left=len(temporary_files(run)))
    result.check(kills >= 2 and mid_write >= 1, f"{kills} kills, {mid_write} during a write: too few to tell")
    if result.check(proc.returncode == 0, f"final run exited {proc.returncode}: {proc.stderr[-300:]}"):
        report = json.loads((run / "report.json").read_text())
        mesh = load_mesh(run / "result.ply")
        result.steps, result.caught = report["result"]["iterations"], report["skipped_steps"]
        result.final_loss = report["losses"][-1] if report["losses"] else None
        result.check(bool(np.all(np.isfinite(mesh.vertices))) and inspect(mesh).closed_manifold,
                     "resumed result not a finite closed manifold")
        result.check(result.final_loss is not None and math.isfinite(result.final_loss), "no finite final loss")
        stages = [e.get("stage") for e in read_events(run)]
        result.check(read_events(run)[-1]["event"] == "done" and "resume" in stages,
                     "the last run did not resume and finish")
    result.problems += run_folder_problems(run)
    result.seconds = round(time.perf_counter() - start, 1)
    return result


@contextlib.contextmanager
def quota_folder(path: Path, size_kb: int):
    """``path`` as a tmpfs of ``size_kb`` (a real full disk: ENOSPC); yields False where
    mounting is not permitted (the caller then limits file sizes instead: EFBIG)."""
    path.mkdir(parents=True, exist_ok=True)
    mounted = False
    if hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("mount"):
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(path)],
                                 capture_output=True).returncode == 0
    try:
        yield mounted
    finally:
        if mounted:
            subprocess.run(["umount", "-l", str(path)], capture_output=True)


def _limit_file_size(limit: int):
    def apply():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def _fill(path: Path) -> None:
    """Write zeros into ``path`` until the disk is full."""
    with contextlib.suppress(OSError), open(path, "wb") as f:
        while True:
            f.write(b"\0" * (64 << 10))
            f.flush()


def full_disk(work: Path, quick: bool) -> Result:
    """``reconstruct`` writing into a tiny quota folder: (a) too small for the first snapshot,
    (b) filled up by another file while the run is under way. Each must end with exit code 2
    and one line naming the file and the fix, leave no temporary file and nothing unreadable;
    (b), once space is freed, must resume to a valid result. Where mounting a tmpfs is not
    permitted, (a) runs with a file-size limit instead and (b) is left out."""
    from ..geometry.mesh import save_mesh

    start = time.perf_counter()
    result = Result("full_disk")
    work = Path(work)
    capture = lit_blob(True).write(work / "capture")
    save_mesh(work / "init.ply", sphere_init(0.7, 4)(quick))  # 5120 faces: a snapshot of about 150 KB
    for scenario, size_kb in (("too_small", 24), ("fills_up", 1024)):
        folder = work / scenario
        run = folder / "run"
        args = _reconstruct_args(capture, run, work / "init.ply", 5120, 400)
        with quota_folder(folder, size_kb) as mounted:
            if not mounted and scenario == "fills_up":
                result.notes[scenario] = "left out: mounting a tmpfs is not permitted here"
                continue
            proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(),
                                    cwd=REPO, preexec_fn=None if mounted else _limit_file_size(size_kb << 10))
            out = ""
            if scenario == "fills_up":
                for line in proc.stdout:  # once the run is under way, fill the disk
                    out += line
                    if '"progress"' in line and '"geometry"' in line:
                        _fill(folder / "filler")
                        break
            more, err = proc.communicate(timeout=600)
            out += more
            lines = err.strip().splitlines()
            result.notes[scenario] = {"quota": f"tmpfs of {size_kb} KB" if mounted else f"files of {size_kb} KB at most",
                                      "exit": proc.returncode, "stderr": lines[-1] if lines else ""}
            result.check(proc.returncode == 2, f"{scenario}: exit code {proc.returncode}, expected 2: {err[-300:]}")
            result.check(len(lines) == 1 and lines[0].startswith("error: ") and "Fix:" in lines[0]
                         and ("no space" in lines[0] or "too large" in lines[0]),
                         f"{scenario}: not one clear line: {err[-300:]}")
            result.check(not temporary_files(run), f"{scenario}: temporary files left: {temporary_files(run)}")
            result.problems += [f"{scenario}: {p}" for p in run_folder_problems(run)]
            events = [json.loads(x) for x in out.splitlines() if x.startswith("{")]
            result.check(bool(events) and events[-1]["event"] == "error", f"{scenario}: the last event is not the error")
            result.steps += max((e.get("iteration") or 0 for e in events if e["event"] == "progress"), default=0)
            if scenario == "fills_up":
                (folder / "filler").unlink()
                done = json.loads((run / "state" / "state.json").read_text())["iteration"]
                resumed = subprocess.run(_reconstruct_args(capture, run, work / "init.ply", 5120, done + 6)
                                         + ["--resume"], capture_output=True, text=True, env=_env(), cwd=REPO,
                                         timeout=600)
                result.check(resumed.returncode == 0,
                             f"resume after freeing space: exit {resumed.returncode}: {resumed.stderr[-300:]}")
                result.problems += [f"after resume: {p}" for p in run_folder_problems(run)]
    result.seconds = round(time.perf_counter() - start, 1)
    return result


# -- the benchmark ----------------------------------------------------------------------------------------------
GRADIENT_CASES = {"gradient_geometry": gradient_geometry, "gradient_meshcolors": gradient_meshcolors}
PROCESS_CASES = {"killed_mid_write": killed_mid_write, "full_disk": full_disk}


def case_names(quick: bool) -> list[str]:
    return list(pipeline_cases(quick)) + list(GRADIENT_CASES) + list(PROCESS_CASES)


def run_case(name: str, work: Path, quick: bool) -> Result:
    """Run one case in ``work`` (an empty folder)."""
    if name in GRADIENT_CASES:
        return GRADIENT_CASES[name](work, quick)
    if name in PROCESS_CASES:
        return PROCESS_CASES[name](work, quick)
    cases = pipeline_cases(quick)
    if name not in cases:
        from ..errors import InputError

        raise InputError(None, f"no stability case '{name}'", f"choose from {', '.join(case_names(quick))}")
    return run_pipeline_case(name, cases[name], work, quick)


def peak_rss_gb() -> float:
    """Peak resident memory of this process so far (Linux reports kilobytes)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (1 << 20)


def guarded(name: str, work: Path, quick: bool) -> dict:
    """``run_case`` with a crash reported as a failed case; peak memory added."""
    start = time.perf_counter()
    try:
        result = run_case(name, work, quick)
    except Exception as err:  # the table reports a crash as a failure instead of stopping
        result = Result(name, problems=[f"crashed: {type(err).__name__}: {err}"])
        result.seconds = round(time.perf_counter() - start, 1)
    result.peak_rss_gb = round(peak_rss_gb(), 2)
    if name.startswith("faces_"):
        result.check(result.peak_rss_gb < MEMORY_LIMIT_GB, f"peak memory {result.peak_rss_gb} GB")
    return result.to_json()


def _child(name: str, work: str, quick: bool, conn) -> None:
    conn.send(guarded(name, Path(work), quick))
    conn.close()


def isolated(name: str, work: Path, quick: bool) -> dict:
    """``guarded`` in a fresh process (its own peak memory; a hard crash is a failure too)."""
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    receive, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(name, str(work), quick, send))
    proc.start()
    send.close()
    try:
        record = receive.recv()
    except EOFError:
        record = Result(name, problems=[f"process died (exit code {proc.exitcode})"]).to_json()
    proc.join()
    if proc.exitcode not in (0, None) and record.get("passed"):
        record["problems"].append(f"process exit code {proc.exitcode}")
        record["passed"] = False
    return record


def _number(x, digits: int = 4) -> str:
    return "-" if x is None else f"{x:.{digits}g}"


def table(records: list[dict]) -> str:
    """The report: one row per case."""
    head = ["case", "steps", "caught", "final loss", "peak GB", "seconds", "result", "note"]
    rows = []
    for r in records:
        notes = r["notes"]
        if r["problems"]:
            note = r["problems"][0]
        elif "relative_errors" in notes:
            note = "max relative error " + f"{100 * max(notes['relative_errors'].values()):.1f}% (final loss column)"
        elif "error" in notes:
            note = "input error: " + notes["error"].split(": ", 1)[-1]
        elif "skipped" in notes:
            note = "skipped: " + "; ".join(notes["skipped"])
        elif "warnings" in notes:
            note = notes["warnings"][-1]
        elif "kills" in notes:
            note = f"{notes['kills']} kills ({notes['killed_during_a_write']} mid-write), resumed"
        elif r["case"] == "full_disk":
            note = "; ".join(f"{k}: exit {v['exit']}" for k, v in notes.items() if isinstance(v, dict))
        else:
            note = ""
        rows.append([r["case"], str(r["steps"]), str(r["caught"]), _number(r["final_loss"]),
                     _number(r["peak_rss_gb"], 3), f"{r['seconds']:.1f}", "pass" if r["passed"] else "FAIL",
                     note[:110]])
    widths = [max(len(head[i]), *(len(row[i]) for row in rows)) for i in range(len(head) - 1)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)) + "  " + head[-1]]
    lines.append("  ".join("-" * w for w in widths) + "  " + "-" * 4)
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)) + "  " + row[-1] for row in rows]
    return "\n".join(lines)


def add_arguments(parser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="the tiny versions the tests run (32 px, a dozen steps, 50k-face case), in this process")
    parser.add_argument("--case", action="append", metavar="NAME", help="run only these cases (repeatable)")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "bench-stability",
                        help="work folder (replaced); results.json is written there")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")


def run(args) -> int:
    from .. import fsio, variant

    if args.variant:
        os.environ["SFT_VARIANT"] = args.variant
    variant.choose(args.variant)
    names = args.case or case_names(args.quick)
    for name in names:
        if name not in case_names(args.quick):
            from ..errors import InputError

            raise InputError(None, f"no stability case '{name}'", f"choose from {', '.join(case_names(args.quick))}")
    out = Path(args.out)
    shutil.rmtree(out / "cases", ignore_errors=True)
    records = []
    for name in names:
        work = out / "cases" / name
        work.mkdir(parents=True, exist_ok=True)
        records.append(guarded(name, work, True) if args.quick else isolated(name, work, False))
        print(f"{name}: {'pass' if records[-1]['passed'] else 'FAIL'} ({records[-1]['seconds']:.1f} s)",
              file=sys.stderr, flush=True)
    fsio.write_json(out / "results.json", {"quick": args.quick, "cases": records}, indent=1)
    print(table(records))
    print("caught: steps the loop skipped and reported (a non-finite loss, gradient or vertex position, "
          "or a step that would put a camera inside the mesh)")
    passed = sum(r["passed"] for r in records)
    print(f"\n{passed}/{len(records)} passed" + ("" if args.quick else "; peak GB per case, each in its own process")
          + (" (peak GB: this process so far)" if args.quick else ""))
    return 0 if passed == len(records) else 1
