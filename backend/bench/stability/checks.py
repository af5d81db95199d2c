"""The checks every case shares: material latents and values, meshes (manifold, self-
intersections), a recording objective that checks every step of a run, and run folders
(every file whole)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ...geometry.mesh import Mesh, load_mesh
from ...geometry.topology import inspect
from ...material import factory
from ...optimize.objective import Objective
from ...optimize.run_folder import RunFolder
from .results import StepLog


# -- checks -------------------------------------------------------------------------------------------
def material_problems(material) -> list[str]:
    """Non-finite latents, or values (float32 sigmoid of the latents, as the BSDF computes
    them) outside the channel's range."""
    channels = material.CHANNELS
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
    import pymeshlab  # here: heavy, and only this check needs it (as in geometry/)

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    return int(ms.current_mesh().selected_face_number())


def mesh_checks(mesh) -> dict:
    report = inspect(mesh)
    return {"faces": mesh.n_faces, "finite": bool(np.all(np.isfinite(mesh.vertices))),
            "manifold": report.closed_manifold, "issues": report.issues,
            "self_intersections": self_intersections(mesh)}


def recorder(inject_nan: set[int] = frozenset(), track_tangles: bool = False):
    """(StepLog, objective factory): the factory, given to ``optimize.run.reconstruct``, records
    every gradient evaluation of the run into the log.

    The loop builds one objective per level; this one is a subclass that checks the
    level's starting mesh, every step's inputs (vertices, material latents and values) and
    outputs (loss, gradients), and otherwise defers to the real objective. ``inject_nan``:
    step indices whose gradient gets a NaN, as a renderer fault would (the loop must skip
    them); ``track_tangles``: count self-intersecting faces at every step (small meshes)."""
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

    return log, RecordingObjective


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
            factory.load(material)
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
