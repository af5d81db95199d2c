"""The brightness factor of a captured environment map, fitted with the staged material.

A captured map's strength is often off (an unknown exposure of the HDR). The scene renders the
map at scale strength x k, and k = exp(latent) is fitted by the material's first texture round
(``material.stages.fit_diffuse`` with ``light``); the material keeps it (``light_factor``), so
every later render of the capture's own lighting uses strength x k."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from .base import LightingFit

ENV_SCALE = "environment.scale"  # the scene parameter: strength x k


class LightFactor(LightingFit):
    """The factor k as one more latent (log k) of a material stage's Adam.

    Args:
        material: the staged material; its ``light_factor`` is k before and after the fit.
        lr: Adam's step on log k.
    """

    NAME = "light"

    def __init__(self, material, lr: float):
        self.material = material
        self._lr = lr
        self.base = 1.0  # the scene's scale at k = 1 (the capture's strength), read by ``prepare``

    @property
    def lr(self) -> float:
        return self._lr

    def present(self, renderer) -> bool:
        return ENV_SCALE in renderer.params

    def prepare(self, renderer, images, weights, views=None) -> None:
        """No closed form: k starts at the material's. Reads base = scene scale / k."""
        self.base = float(renderer.params[ENV_SCALE][0]) / self.material.light_factor

    def initial(self):
        return mi.Float(math.log(self.material.light_factor))

    def apply(self, renderer, latent) -> None:
        renderer.params[ENV_SCALE] = self.base * dr.exp(latent)
        renderer.params.update()

    def penalty(self, latent):
        """No prior on k."""
        return mi.Float(0.0)

    def finish(self, renderer, latent) -> None:
        self.material.light_factor = float(np.exp(dr.detach(latent)[0]))
        self.reset(renderer)

    def reset(self, renderer) -> None:
        renderer.params[ENV_SCALE] = mi.Float(self.base * self.material.light_factor)
        renderer.params.update()
