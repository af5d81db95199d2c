"""The albedo x light scale convention of the fitted lighting models.

Images fix only the product of albedo and light: an albedo s times brighter under a light
s times dimmer renders the same. Every lighting model fitted with the material
(backend.lighting.base.LightingModel) settles this one free scale the same way: after each
material stage, albedo and specular are multiplied by s = ``ALBEDO_CONVENTION`` / mean albedo
and the light divided by s, so the object's mean albedo (over its faces and the three
channels) is ``ALBEDO_CONVENTION``; the renders do not change while no value clips at 1.

The product is free per colour channel too: a bluer albedo under a yellower light renders
the same diffuse image. A flash is white (one scalar intensity); an estimated map starts
white and the fit settles the split, unforced afterwards, since forcing the map white moves
the specular lobe's colour (one scalar, lit by the map). Scoring under another light
therefore treats the colour as free, as the scale (backend.metrics.evaluate)."""

from __future__ import annotations

import numpy as np

ALBEDO_CONVENTION = 0.5  # the object's mean albedo (over its surface and the three channels)


def describe(light: str) -> str:
    """The convention in words, for reports and events (``light``: what is rescaled with the albedo)."""
    return f"mean albedo of the object = {ALBEDO_CONVENTION} ({light} and albedo rescaled together after each stage)"


def mean_albedo(material) -> float:
    """The object's mean albedo: over faces (per-face mean of mesh colors, or the face's
    material constant) and the three channels."""
    values = material.values("albedo")
    if material.channels["albedo"].kind == "colors":
        return float(values[material.layout.entries].mean())
    return float(values[material.labels].mean())


def normalise_albedo(material) -> float:
    """Albedo and specular multiplied by s so the mean albedo is ``ALBEDO_CONVENTION`` (values
    kept inside (0, 1)); returns s (1 when the albedo is black: nothing to set). The caller
    divides its light by s."""
    mean = mean_albedo(material)
    if not mean > 1e-6:
        return 1.0
    s = ALBEDO_CONVENTION / mean
    for name in ("albedo", "specular"):
        ch = material.channels[name]
        material.set_values(name, np.clip(material.values(name) * s, 1e-4, 1 - 1e-4), ch.kind)
    return s
