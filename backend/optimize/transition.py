"""Between two levels: re-mesh when the surface has become inconsistent (ray casting +
screened Poisson), else subdivide 1-to-4 and simplify to the face budget. Either way the
material is carried over: resampled at the closest points of the old surface. A re-mesh
that adds handles no view sees through is not applied (``remesh.handles_supported``)."""

from __future__ import annotations

import time

from ..geometry.poisson import SurfaceReconstructionError
from ..geometry.remesh import rebuild, visible_samples
from ..geometry.subdivide import midpoint
from ..geometry.topology import inspect


def transition(fit, appearance) -> None:
    """Re-mesh when needed, else subdivide 1-to-4 and honour the face budget. ``fit``: the
    run's optimize.levels.Fit, whose ``state.mesh`` and ``material`` change; ``appearance``:
    the run's Appearance, told of a re-mesh."""
    c, s = fit.config, fit.state
    old = s.mesh
    if c.remesh != "never" and _remesh(fit, appearance, old):
        return
    start = time.perf_counter()
    fit.emit("stage", stage="refine", level=s.level, faces=old.n_faces)
    fine, _ = midpoint(old)
    s.mesh = s.budget.enforce(fine)
    if s.mesh is fine:
        fit.material.on_subdivide(old, fine)
    else:
        # the simplified mesh lies on the old surface: resample the mesh colors rather than
        # restart them from grey, so the next level's steps see the fitted material
        fit.material.on_remesh(s.mesh, old_mesh=old, reset=False)
    s.timed("refine", start)


def _remesh(fit, appearance, old) -> bool:
    """The re-mesh check after a level, recorded in its LevelRecord; True when applied."""
    c, s = fit.config, fit.state
    start = time.perf_counter()
    fit.emit("stage", stage="remesh", level=s.level, faces=old.n_faces)
    fit.progress.update(force=True, stage="remesh", level=s.level, faces=old.n_faces)
    cameras = [v.camera for v in fit.viewset.views]
    masks = [v.mask for v in fit.viewset.views] if fit.capture.has_masks else None
    samples = visible_samples(old, cameras, masks)
    hits = len(samples.points) + samples.back_faces + samples.outside_masks
    share = (samples.back_faces + samples.outside_masks) / max(hits, 1)
    remeshed, handles = None, None
    if c.remesh == "always" or share > c.remesh_threshold:
        target = s.budget.next_target(old.n_faces)
        try:
            remeshed, handles = rebuild(samples, old, target, cameras, masks)
        except SurfaceReconstructionError as err:  # the current surface stays; the level goes on
            fit.emit("warning", message=f"re-meshing not applied: {err}")
            remeshed = None
        else:
            # the rebuilt surface lies on the old one where the views agree: resample the fitted
            # material instead of restarting it from grey, which cost every level a refit
            fit.material.on_remesh(remeshed, old_mesh=old, reset=False)
            appearance.on_remesh(remeshed, fit.material, fit.viewset.at(c.coarse_size))
            s.mesh = remeshed
    s.timed("remesh", start)
    s.levels[-1].remesh = {"seconds": round(time.perf_counter() - start, 3),
                           "inconsistent_share": round(share, 5), "back_faces": samples.back_faces,
                           "outside_masks": samples.outside_masks, "applied": remeshed is not None,
                           "faces": None if remeshed is None else remeshed.n_faces,
                           "genus": None if remeshed is None else inspect(remeshed).genus, "handles": handles}
    return remeshed is not None
