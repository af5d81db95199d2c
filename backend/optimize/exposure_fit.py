"""The per-frame gains (backend.lighting.exposure) in a run: where their targets come from,
when they are solved and what they render (``ExposureFit``)."""

from __future__ import annotations

import numpy as np

from ..lighting import exposure as model
from ..material.stages import silhouette_weights
from ..render.scene import RenderSettings


class ExposureFit:
    """The run's ``Exposure`` and the ViewSet whose targets it divides (``viewset.exposure``).

    Args:
        viewset: the run's views (backend.optimize.views.ViewSet), in capture order.
        max_size: the run's largest image size; a solve renders at most ``model.SOLVE_SIZE``.
        max_depth: the path depth of the solve's renders (the material stages').
    """

    def __init__(self, viewset, max_size: int, max_depth: int):
        self.viewset, self.max_size, self.max_depth = viewset, max_size, max_depth
        self.exposure = viewset.exposure = model.Exposure([v.name for v in viewset.views])

    @classmethod
    def start(cls, capture, config, viewset, staged: bool, warn) -> "ExposureFit | None":
        """The fit when ``config.exposure`` asks for one on ``capture`` (``model.enabled``);
        it needs the staged material's cycles (else ``warn`` and None)."""
        if not model.enabled(config.exposure, capture):
            return None
        if not staged:
            warn("--exposure fits per-frame gains between the material stages of --material staged: "
                 "this run keeps one exposure for all frames")
            return None
        return cls(viewset, config.max_size, config.max_depth)

    def current(self, views):
        """``views`` with their targets under the latest gains (the same size, from the ViewSet)."""
        if not views:
            return views
        return self.viewset.at(max(views[0].camera.width, views[0].camera.height))

    def solve(self, renderer_for) -> np.ndarray:
        """Gains from renders of every frame (``renderer_for(views, settings)``: a renderer of
        the current mesh, material and light) against the frames as recorded, weighed by the
        mask less its outline band (``Exposure.solve``)."""
        views = self.viewset.at(min(model.SOLVE_SIZE, self.max_size), recorded=True)
        renderer = renderer_for(views, RenderSettings(spp=model.SOLVE_SPP, max_depth=self.max_depth, integrator="prb"))
        renders = [renderer.render_numpy(i, seed=7919 + i)[..., :3] for i in range(len(views))]
        weights = [silhouette_weights([v.mask], 1)[0] if v.mask is not None else (r.max(-1) > 0).astype(np.float32)
                   for v, r in zip(views, renders)]
        return self.exposure.solve(renders, [v.target for v in views], weights)
