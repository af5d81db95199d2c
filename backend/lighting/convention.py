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
therefore treats the colour as free, as the scale (backend.metrics.evaluate).

The user can set the scale instead (``AlbedoScale``: ``reconstruct --known-albedo`` and
``--map-calibrated``). ``known`` multiplies by s = mean(colour) / mean over the channels of
the object's median albedo per channel, so the median albedo has the colour's level (one
scalar: a flash and a map's brightness factor are white, so only the level is the user's and
the colour split stays the fit's). ``map`` keeps a captured map's strength (its brightness
factor is not fitted), so the map sets the scale. ``mean`` is the default above for fitted
lights; with the capture's own lights the scale is theirs (point lights: as given; a captured
map: its strength x the brightness factor fitted in the first texture stage)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

ALBEDO_CONVENTION = 0.5  # the object's mean albedo (over its surface and the three channels)


def describe(light: str) -> str:
    """The convention in words, for reports and events (``light``: what is rescaled with the albedo)."""
    return f"mean albedo of the object = {ALBEDO_CONVENTION} ({light} and albedo rescaled together after each stage)"


@dataclass(frozen=True)
class AlbedoScale:
    """What sets the albedo's scale: ``mean`` (the object's mean albedo is
    ``ALBEDO_CONVENTION``), ``known`` (its median albedo has the level of ``colour``, linear
    RGB in (0, 1)) or ``map`` (a captured map's strength, calibrated: its factor stays 1)."""

    mode: str = "mean"
    colour: tuple[float, float, float] | None = None

    @classmethod
    def from_config(cls, config) -> "AlbedoScale":
        known = getattr(config, "known_albedo", None)
        if known is not None:
            return cls("known", tuple(float(x) for x in known))
        return cls("map") if getattr(config, "map_calibrated", False) else cls()

    def describe(self, light: str) -> str:
        """The convention in words (``light``: what is rescaled with the albedo)."""
        if self.mode == "known":
            rgb = ", ".join(f"{x:g}" for x in self.colour)
            return (f"known albedo: median albedo of the object at the level of ({rgb}) "
                    f"({light} and albedo rescaled together after each stage)")
        if self.mode == "map":
            return "map strength calibrated: the captured map's strength sets the albedo (no brightness factor fitted)"
        return describe(light)

    def factor(self, material) -> float:
        """The s that albedo and specular are multiplied by (and the light divided by), from
        the material as it is; 1 when the albedo is black."""
        if self.mode == "known":
            level = float(median_albedo(material).mean())
            return float(np.mean(self.colour)) / level if level > 1e-6 else 1.0
        mean = mean_albedo(material)
        return ALBEDO_CONVENTION / mean if mean > 1e-6 else 1.0

    def report(self, light: str) -> dict:
        """report.json ``albedo_scale``: the mode, its colour and the convention in words."""
        return {"mode": self.mode, "colour": None if self.colour is None else list(self.colour),
                "convention": self.describe(light)}


def face_albedo(material) -> np.ndarray:
    """The albedo per face (F, 3): the mean of its mesh colors, or its material's constant."""
    values = material.values("albedo")
    if material.channels["albedo"].kind == "colors":
        return values[material.layout.table].mean(axis=1)
    return values[material.labels]


def median_albedo(material) -> np.ndarray:
    """The object's median albedo per channel, over its faces (3,)."""
    return np.median(face_albedo(material).reshape(-1, 3), axis=0)


def mean_albedo(material) -> float:
    """The object's mean albedo: over faces (per-face mean of mesh colors, or the face's
    material constant) and the three channels."""
    values = material.values("albedo")
    if material.channels["albedo"].kind == "colors":
        return float(values[material.layout.entries].mean())
    return float(values[material.labels].mean())


def normalise_albedo(material, scale: AlbedoScale | None = None) -> float:
    """Albedo and specular multiplied by s so the mean albedo is ``ALBEDO_CONVENTION`` (or as
    ``scale`` sets it; values kept inside (0, 1)); returns s (1 when the albedo is black:
    nothing to set). The caller divides its light by s."""
    s = (scale or AlbedoScale()).factor(material)
    if s != 1.0:
        rescale_albedo(material, s)
    return s


def rescale_albedo(material, s: float) -> None:
    """Albedo and specular times ``s``, kept inside (0, 1)."""
    for name in ("albedo", "specular"):
        ch = material.channels[name]
        material.set_values(name, np.clip(material.values(name) * s, 1e-4, 1 - 1e-4), ch.kind)


def check_scale(config, staged: bool, fitted: bool, has_map: bool) -> None:
    """``--map-calibrated`` and ``--known-albedo`` need the staged material (``staged``) and a
    light whose scale they can set: a captured map (``has_map``) for the first, it or a fitted
    light (``fitted``) for the second. InputError otherwise, before any work."""
    known, calibrated = getattr(config, "known_albedo", None), getattr(config, "map_calibrated", False)
    if known is None and not calibrated:
        return
    flag = "--known-albedo" if known is not None else "--map-calibrated"
    if known is not None and calibrated:
        raise InputError(None, "--known-albedo and --map-calibrated both set the albedo's scale", "give one of them")
    if not staged:
        raise InputError(None, f"{flag} sets the scale of the staged material", f"add --material staged or drop {flag}")
    if calibrated and (fitted or not has_map):
        raise InputError(None, "--map-calibrated keeps a captured map's strength, and this run fits its light "
                               f"(--lighting {config.lighting}) or has no map",
                         "give the map with --env HDR, or drop --map-calibrated")
    if known is not None and not fitted and not has_map:
        raise InputError(None, "--known-albedo rescales the light with the albedo, and the capture's point lights "
                               "are given (they set the scale)", "drop --known-albedo")


def scale_report(scale: AlbedoScale, light: str, fitted: bool, has_map: bool, material=None) -> dict:
    """report.json ``albedo_scale``: what set the albedo's scale (``mode``: mean, known, map,
    light factor or lights), in words (``convention``), and the object's ``median_albedo``
    (per channel, of ``material`` when given)."""
    if fitted or scale.mode != "mean":
        out = scale.report(light)
    elif has_map:
        k = float(getattr(material, "light_factor", 1.0))
        out = {"mode": "light factor", "colour": None,
               "convention": f"the captured map's strength x a brightness factor k = {k:.4g} fitted with the albedo "
                             "(--map-calibrated keeps the strength, --known-albedo sets the level)"}
    else:
        out = {"mode": "lights", "colour": None, "convention": "the capture's point lights, as given"}
    if material is not None:
        out["median_albedo"] = [round(float(x), 5) for x in median_albedo(material)]
    return out
