"""The albedo x light scale convention of the fitted lighting models.

Images fix only the product of albedo and light: an albedo s times brighter under a light
s times dimmer renders the same. Every lighting model fitted with the material
(``--lighting estimate``: backend.lighting.estimate; ``--lighting flash``:
backend.lighting.flash) settles this one free scale the same way: after each material
stage, albedo and specular are multiplied by s = ``ALBEDO_CONVENTION`` / mean albedo and
the light divided by s, so the object's mean albedo (over its faces and the three
channels) is ``ALBEDO_CONVENTION``; the renders do not change while no value clips at 1.

The product is free per colour channel too: a bluer albedo under a yellower light renders
the same diffuse image. A flash is white (one scalar intensity). An estimated map is made
white on average before each stage (``neutral_colour``: its solid-angle mean has equal
channels), as a white-balanced camera sees its light, so the albedo carries the object's
colour. Without it the split is wherever the fit stopped from its first guess, and an albedo
carried under another light takes the old light's colour with it. The diffuse image does not
change; the specular lobe, one scalar, takes the light's colour, so the step comes before a
stage, whose fit settles the highlights again (made after a stage, the step left the final
highlights off the fit: docs/results.md, "The colour of the light")."""

from __future__ import annotations

import numpy as np

ALBEDO_CONVENTION = 0.5  # the object's mean albedo (over its surface and the three channels)


def describe(light: str, colour: bool = False) -> str:
    """The convention in words, for reports and events (``light``: what is rescaled with the
    albedo; ``colour``: its mean colour is made white as well)."""
    white = f", the {light} white on average (the albedo carries the colour)" if colour else ""
    return (f"mean albedo of the object = {ALBEDO_CONVENTION}{white} "
            f"({light} and albedo rescaled together after each stage)")


def mean_albedo(material) -> float:
    """The object's mean albedo: over faces (per-face mean of mesh colors, or the face's
    material constant) and the three channels."""
    values = material.values("albedo")
    if material.channels["albedo"].kind == "colors":
        return float(values[material.layout.table].mean())
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


def neutral_colour(material, light_mean) -> np.ndarray:
    """The colour half of the convention: albedo multiplied per channel by k = light_mean /
    its mean over channels (values kept inside (0, 1)), so that the light divided by k is
    white on average; returns k (ones for a light with a black channel). The caller divides
    its light by k; ``normalise_albedo`` then settles the scale."""
    light_mean = np.asarray(light_mean, np.float64)
    if not float(light_mean.min()) > 1e-12:
        return np.ones(3)
    k = light_mean / light_mean.mean()
    material.set_values("albedo", np.clip(material.values("albedo") * k, 1e-4, 1 - 1e-4),
                        material.channels["albedo"].kind)
    return k
