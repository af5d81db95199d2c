"""The final appearance stage: the material fitted once more at the frames' own resolution.

The geometry levels and the material stages fit images of at most ``max_size`` pixels, so a
texture finer than those images cannot be seen by them. Once everything else has ended, this
stage gives every face a mesh-color resolution from the frames' pixel footprint on it
(``material.footprint``: about one sample per pixel where the face is seen largest), carries
the fitted material over to that layout (each face's grid resampled from the old one), and
fits the mesh-color channels by Adam against the frames at their own size (``texture_size``
caps it): geometry frozen, no silhouette gradients (a material render), the lighting held as
the run fitted it (its light factor, map or flash), highlights included, a 1-pixel band
inside each mask outline left out. The stage is kept only when it lowers the loss on the
validation views at its size; otherwise the material goes back to what it was.

Time: with a time budget the stage has ``budget.TEXTURE_RESERVE`` of it held back for it (the
material stages and polish rounds end that much earlier; ``Budget.texture_share``). Once the
geometry levels have ended (``size_reserve``) one render at the stage's size is timed and the
share becomes what the stage is then expected to take, ``RESERVE_MARGIN`` x (its frames'
loading, its scene and kernels, and (2 x validation views + ``RENDERS_PER_ITERATION`` x
``texture_iterations``) renders and the iterations' host work), at most ``TEXTURE_RESERVE``.
A fixed share would hold back time the polish rounds could use wherever the stage needs less
of it. The stage times a few iterations and runs as many more as the time left allows, at
most ``texture_iterations``.

``--texture-stage auto`` (default) runs it when the capture's frames are larger than
``max_size``; ``on`` always (at the frames' size, even when that is the fit's); ``off`` never.
``report.json`` ``texture_stage`` says what it did: the image size it fitted, the fit's
``max_size``, the resolutions it chose, its iterations, losses and seconds."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ..capture.model import Capture
from ..material.footprint import face_footprints, footprint_resolutions
from ..material.stages import FitSettings, evaluate_loss, fit, silhouette_weights
from ..render.scene import RenderSettings, SceneRenderer
from .appearance import lit_environment
from .budget import TEXTURE_RESERVE
from .views import ViewSet, validation_views

MODES = ("auto", "on", "off")
PROBE_ITERATIONS = 3  # timed first, to size the rest of the stage to the time left
RENDERS_PER_ITERATION = 3.0  # a fitted view (render, backward pass, update) in renders' time
ITERATION_HOST_S = 0.05  # and its host work (the AD graph, the loss, Adam's update), seconds
RESERVE_MARGIN = 1.25  # the reserve over the stage's expected time (``size_reserve``)
MAX_SAMPLES = 1_000_000  # most mesh-color entries (sum of (r + 1)(r + 2) / 2 over the faces)


def native_size(capture: Capture) -> int:
    """The long side of the capture's largest frame, pixels."""
    return max(max(f.camera.width, f.camera.height) for f in capture.frames)


class TextureStage:
    """Whether the stage runs for this capture and settings, and the stage itself (``run``)."""

    def __init__(self, capture: Capture, config, staged: bool):
        self.capture, self.config = capture, config
        mode = getattr(config, "texture_stage", "auto")
        if mode not in MODES:
            raise ValueError(f"texture_stage must be one of {', '.join(MODES)}, not {mode!r}")
        native = native_size(capture)
        cap = getattr(config, "texture_size", None)
        self.size = min(native, cap) if cap else native
        if not staged:
            self.enabled, reason = False, "no mesh-color material (--material staged runs it)"
        elif mode == "off":
            self.enabled, reason = False, "--texture-stage off"
        elif mode == "on":
            self.enabled, reason = True, "--texture-stage on"
        elif self.size > config.max_size:
            self.enabled, reason = True, f"frames of {self.size} px are larger than the fit's {config.max_size} px"
        else:
            self.enabled, reason = False, f"frames of {self.size} px are no larger than the fit's {config.max_size} px"
        self.record: dict = {"mode": mode, "enabled": self.enabled, "reason": reason, "size": self.size,
                             "fit_size": config.max_size, "ran": False, "reserve": None}
        self._views = None  # the frames at the stage's size, once ``size_reserve`` loaded them

    def report(self, levels) -> dict:
        """``report.json`` ``texture_stage``: the stage's record and ``sizes``, the image size
        each stage of the run fitted (``levels``: the run's LevelRecords)."""
        return dict(self.record, sizes=_sizes(levels, self.config.max_size, self.record))

    def reserve_share(self) -> float:
        """The share of a time budget held back for this stage (0 when it does not run)."""
        return TEXTURE_RESERVE if self.enabled else 0.0

    def size_reserve(self, mesh, material, appearance, budget) -> None:
        """Once the geometry levels have ended: ``budget.texture_share`` from one render at the
        stage's size with the current ``mesh`` and ``material`` (see the module; at most the
        initial ``TEXTURE_RESERVE``). The frames loaded for it are kept for ``run``. Without a
        time budget, or when the stage does not run, nothing changes."""
        budget_s = self.config.time_budget_s
        if not self.enabled or not budget_s or self.record.get("reserve") is not None:
            return
        start = time.perf_counter()
        self._views = ViewSet(self.capture, self.size).views
        load_s = time.perf_counter() - start
        renderer = self._renderer(mesh, material, appearance, [self._views[len(self._views) // 2]])
        t = time.perf_counter()
        renderer.render_numpy(0, seed=7)  # compiles the render's kernels
        first_s = time.perf_counter() - t
        t = time.perf_counter()
        renderer.render_numpy(0, seed=8)
        render_s = time.perf_counter() - t
        iterations = int(getattr(self.config, "texture_iterations", 60))
        renders = 2 * len(validation_views(len(self._views), self.config.validation_views)) \
            + RENDERS_PER_ITERATION * iterations
        # the stage builds its own scene and compiles a render and a fit (forward and backward
        # kernels): the first render's compilation RENDERS_PER_ITERATION times over
        setup_s = t - start - load_s - first_s + RENDERS_PER_ITERATION * max(first_s - render_s, 0.0)
        expected = load_s + setup_s + renders * render_s + iterations * ITERATION_HOST_S
        share = min(budget.texture_share, RESERVE_MARGIN * expected / budget_s)
        budget.texture_share = share
        self.record["reserve"] = {"share": round(share, 4), "expected_s": round(expected, 2),
                                  "render_s": round(render_s, 4), "seconds": round(time.perf_counter() - start, 3)}

    def _renderer(self, mesh, material, appearance, views) -> SceneRenderer:
        """The stage's material render of ``views``: highlights included, the lighting as fitted."""
        base = RenderSettings(spp=self.config.spp, max_depth=self.config.max_depth, integrator="prb")
        return SceneRenderer(mesh, material.field, [v.camera for v in views], [v.lights for v in views],
                             lit_environment(self.capture, material), appearance.material_settings(base))

    def run(self, mesh, material, appearance, budget, emit, level: int = 0) -> dict:
        """Fit ``material`` on ``mesh`` at the stage's image size, in place, within ``budget``
        (the run's Budget; the share held back for the stage is released here). Returns the
        record for ``report.json`` (also sent as a ``texture`` event)."""
        budget.texture_share = 0.0
        if not self.enabled:
            return self.record
        start = time.perf_counter()
        emit("stage", stage="texture", level=level, faces=mesh.n_faces)
        views = self._views or ViewSet(self.capture, self.size).views
        self._views = None
        footprint = face_footprints(mesh, [v.camera for v in views])
        resolutions = footprint_resolutions(footprint, max_samples=MAX_SAMPLES)
        saved = _save(material)
        material.make_spatial("albedo")
        material.set_resolution(resolutions)
        names = [n for n in ("albedo", "specular", "roughness")
                 if material.channels[n].kind == "colors" and n in material.trainable]
        renderer = self._renderer(mesh, material, appearance, views)
        images = [v.target for v in views]
        masks = [v.mask for v in views] if all(v.mask is not None for v in views) else None
        settings = appearance.driver.settings if appearance.driver is not None else FitSettings()
        settings = replace(settings, variance_weight=0.0)
        weights = silhouette_weights([np.ones(i.shape[:2], np.float32) for i in images] if masks is None else masks,
                                     settings.edge_erosion)
        check = validation_views(len(views), self.config.validation_views)
        t = time.perf_counter()
        before = evaluate_loss(renderer, images, weights, material, views=check)
        eval_s = time.perf_counter() - t
        iterations, losses = 0, []
        most = int(getattr(self.config, "texture_iterations", 60))
        probe = min(PROBE_ITERATIONS, most)
        probe_s = 3.0 * probe * eval_s / max(len(check), 1)  # a fitted view: about 3 renders' time
        if budget.fits(eval_s + probe_s):
            t = time.perf_counter()
            result = fit(renderer, images, weights, material, names, replace(settings, iterations=probe),
                         stage="texture", emit=emit)
            per = (time.perf_counter() - t) / probe
            iterations, losses = probe, list(result.losses)
            more = most - probe
            if self.config.time_budget_s:
                left = self.config.time_budget_s - budget.elapsed() - budget.finish_s() - eval_s
                more = min(more, max(0, math.floor(left / per)))
            if more > 0:
                result = fit(renderer, images, weights, material, names, replace(settings, iterations=more),
                             stage="texture", emit=emit)
                iterations += more
                losses += result.losses
        after = evaluate_loss(renderer, images, weights, material, views=check) if iterations else before
        kept = iterations > 0 and after < before
        if not kept:
            _restore(material, saved)
        r = resolutions
        self.record.update({
            "ran": True, "kept": kept, "image_size": [views[0].camera.width, views[0].camera.height],
            "channels": names, "iterations": iterations, "loss_before": before, "loss_after": after,
            "resolution": {"min": int(r.min()), "median": float(np.median(r)), "max": int(r.max()),
                           "samples": int(material.layout.n_samples) if kept else None,
                           "footprint_px_median": round(float(np.median(footprint)), 3),
                           "unseen_faces": int((footprint == 0).sum())},
            "last_loss": losses[-1] if losses else None, "seconds": round(time.perf_counter() - start, 3)})
        emit("texture", **self.record)
        return self.record


def _sizes(levels, fit_size: int, record: dict) -> dict:
    """The image size (long side, pixels) each stage of the run fitted."""
    return {"levels": [lv.size for lv in levels if not lv.polish], "polish": [lv.size for lv in levels if lv.polish],
            "final_material": fit_size, "texture": max(record["image_size"]) if record.get("kept") else None}


def _save(material) -> dict:
    return {"resolutions": material.resolutions.copy(), "uniform": material.layout.uniform,
            "values": {n: (ch.kind, material.values(n).copy()) for n, ch in material.channels.items()}}


def _restore(material, saved: dict) -> None:
    r = saved["resolutions"]
    material.set_resolution(int(r[0]) if saved["uniform"] and len(r) else r)
    for name, (kind, values) in saved["values"].items():
        material.set_values(name, values, kind)
