"""Settings of a reconstruction run (the ``reconstruct`` command's options and the schedule)."""

from __future__ import annotations

from dataclasses import dataclass

# Mesh colors tie the texture's resolution to the mesh, and the smooth-shaded specular lobe shows
# every facet of the surface, so a staged run grows faces faster than the paper's rule
# (figures: docs/results.md).
STAGED_FACE_GROWTH = 1.5


@dataclass
class ReconstructConfig:
    # what to start from and what to fit
    init: str | None = None  # carve | sphere | box | spheres | points | FILE; None = by the capture
    material: str = "auto"  # auto (constant, estimated), staged (mesh colors schedule) or known:R,G,B:SPEC:ROUGH
    # staged materials of a capture without material masks: the frames' colours clustered into
    # this many (1: one material), or "auto" (backend.material.labels.choose_material_count)
    n_materials: int | str = 1
    effects: str = "auto"  # light-transport effects: auto (measured), all, or a list (see render/effects.py)
    # captured (the capture's lights) or estimate (an environment map fitted with the material,
    # backend.lighting.estimated_map); the command resolves its default (backend.lighting.modes)
    lighting: str = "captured"
    # per-frame exposure and white balance (backend.lighting.exposure): auto (real captures),
    # off, per-frame
    exposure: str = "auto"
    # each frame's pose and the shared intrinsics refined between geometry levels
    # (backend.optimize.camera_fit): auto (solved or measured cameras), on, off; camera_sweeps:
    # sweeps over every view in one refinement
    refine_cameras: str = "auto"
    camera_sweeps: int = 6
    camera_newton: int = 3  # Gauss-Newton steps on each frame's pose after the sweeps (camera_newton)
    # what sets the albedo's scale (backend.lighting.convention.AlbedoScale): a captured map's
    # strength kept (no brightness factor fitted), or the level of the object's median albedo
    map_calibrated: bool = False
    known_albedo: tuple[float, float, float] | None = None
    initial_faces: int = 5000  # face count of the initial mesh; the budget D starts at twice this
    max_faces: int = 250_000  # refinement stops once the budget would exceed this
    # None: the face budget grows by initial_faces / 2 a level (the paper); else it is multiplied
    # by this. The command line defaults to STAGED_FACE_GROWTH for --material staged.
    face_growth: float | None = None
    # limits
    time_budget_s: float | None = None  # wall clock for the whole run (initialisation included)
    iterations: int | None = None  # total optimisation steps over all levels
    seed: int = 0
    # images
    max_size: int = 256  # long side of the finest images, pixels
    coarse_size: int = 64  # long side at level 0; doubles every level up to max_size
    views_per_step: int = 2
    # rendering
    integrator: str = "direct_projective"  # or prb_projective (with max_depth) for interreflections
    max_depth: int = 3
    spp: int = 16  # samples per pixel for the interior (continuous) part of the gradient
    # samples per pixel of a geometry step's primal image (0: spp). The loss's adjoint is the
    # residual t(render) - t(target), so the primal's noise multiplies every pixel's derivative;
    # more primal samples give a cleaner direction per second of a step (bench samples), which
    # has not yet shown in a budgeted run's F1 (docs/notes/2026-12-02-sample-counts.md)
    primal_spp: int = 0
    sppp: int = 4  # samples per pixel for the silhouette part (the costlier one)
    validation_views: int = 6
    validation_spp: int = 16
    # steps
    tone: str = "log"  # loss on log(1 + x / mean radiance) ("linear": the paper's plain MSE)
    # Large Steps smoothing (I + lambda L) and the per-vertex gradient cap (percentile; 0: off).
    # None: chosen per capture by backend.optimize.stiffness (soft 2 / 95, or stiff 20 / 99.5 when
    # one constant material must absorb a textured appearance). A stiff system moves only the
    # smoothest modes, so detail converges slowly; below lambda 1 steps start to backtrack.
    lambda_: float | None = None
    step: float = 0.1  # largest step per iteration, as a fraction of the mean edge length
    clip: float | None = None
    material_warmup: int = 60  # material-only steps before the first geometry step (estimated material)
    material_lr: float = 0.03  # Adam step on material latents (logits)
    light_first_cycles: int = 3  # a fitted lighting's most constant-material cycles before level 0
    # a fitted lighting and the material restart and are fitted again on the final surface, when
    # this share of a time budget is left (see Appearance.finalise); None: never
    relight_reserve: float | None = 0.2
    # convergence (see backend.optimize.convergence)
    eval_every: int = 10  # steps between validation losses
    plateau_tolerance: float = 0.005
    patience: int = 3
    backtrack: float = 0.02  # a validation loss this much above the best: revert, halve the step
    min_step_scale: float = 0.125  # a level ends when its step has shrunk this far and plateaued
    level_iterations: int = 400
    min_level_iterations: int = 30
    max_levels: int = 12
    level_tolerance: float = 0.003
    min_levels: int = 1  # levels run before the level_tolerance test may end refinement
    # with --material staged: geometry rounds at the final face count under the fitted material
    # (see optimize.run.Reconstruction._polish), while a round lowers the validation loss by polish_tolerance
    polish_rounds: int = 4
    polish_tolerance: float = 0.01
    # a polish round keeps its step and ends when the mean of the last polish_window validation
    # losses has not set a new best for polish_patience evaluations, or after
    # polish_length x level_iterations steps
    polish_window: int = 3
    polish_patience: int = 10
    polish_length: int = 2
    polish_warmup: int = 10  # steps over which the step grows to its full length
    polish_divergence: float = 0.25  # a validation loss this much above the best: back, step halved
    # most material cycles once geometry has converged, and after each polish round (the
    # schedule's own end usually comes first)
    final_material_cycles: int = 12
    # the final texture stage at the frames' own size (backend.optimize.texture_stage): auto (when
    # the frames are larger than max_size), on or off; texture_size caps its images' long side
    # (None: the frames' own); texture_iterations: its most Adam iterations
    texture_stage: str = "auto"
    texture_size: int | None = None
    texture_iterations: int = 60
    # re-meshing between levels: auto = when ray casting finds back faces or geometry outside
    # the masks on more than remesh_threshold of the hits
    remesh: str = "auto"
    remesh_threshold: float = 0.002
    # output
    snapshot_every_s: float = 1.0  # the add-on streams an update every second...
    snapshot_share: float = 0.05  # ...or less often, so that writing snapshots takes at most this share of the time
    track_metrics: bool = False  # metrics after every level (charged to the budget)
    # held-out PSNR against run time (backend.planning.tracking; its time is charged to the budget):
    # the capture's ground-truth held-out views, else every held_out_every-th view, not fitted
    track_accuracy: bool = False
    held_out_every: int = 8
    accuracy_every_s: float = 30.0  # seconds of run time between scores (and at every level's and stage's end)
    accuracy_views: int = 4  # views scored, spread over the held-out ones
    accuracy_size: int = 128  # long side of the scored images (at most max_size)
    accuracy_spp: int = 16

