"""A point light at every camera (``--lighting flash``: a phone's flash, DTU-like captures),
its intensity fitted with the material.

Model. Frame f is lit by one isotropic point light at its camera centre c_f, of radiant
intensity I (W/sr; one scalar shared by all frames, or RGB with ``rgb``), and by nothing else
(the capture's own lights are replaced, a captured map withheld). Its direct light on a
Lambertian point x of albedo rho and normal n is Mitsuba's point emitter:

    L(x) = rho / pi * I * max(0, n . w) / r^2,    w = (c_f - x) / r,  r = |c_f - x|

plus the specular lobe and, with more bounces, interreflections, all linear in I. Parameter:
I = exp(latent), so it stays positive. It starts from what the frames show
(``initial_intensity``); every material stage first solves it in closed form for the material
as it is (``FlashFit.prepare``), then fits it by Adam with the material (``FlashFit``, through
the renderer's light scale). Geometry steps render with it and leave it fixed.

Scale. Images fix only rho x I; after each stage the scale convention multiplies albedo and
specular by s and divides I by s (backend.lighting.convention), and the report gives I under
it. An RGB intensity is ambiguous with the albedo's colour as well (the convention fixes only
the mean), so the command fits one scalar."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..capture.images import read_linear_rgb, read_mask
from ..capture.model import Capture, PointLight
from .base import LightingFit, LightingModel
from .convention import ALBEDO_CONVENTION, describe, normalise_albedo

CONVENTION = describe("flash intensity")
INIT_FRAMES = 16  # frames read (evenly spread) for the initial intensity
SOLVE_VIEWS = 8  # views rendered (evenly spread) for a stage's closed-form intensity
MEAN_COSINE = 2.0 / 3.0  # n . w averaged over a sphere's visible pixels, lit from the camera


def place(capture: Capture, intensity) -> None:
    """Every frame lit by one point light of ``intensity`` (scalar or RGB, W/sr) at its camera
    centre, replacing its own. The frames' light lists change in place, so views and
    renderers holding them see the new lights."""
    rgb = np.broadcast_to(np.asarray(intensity, np.float64), (3,)).copy()
    for frame in capture.frames:
        frame.lights[:] = [PointLight(frame.camera.centre, rgb.copy())]


def initial_intensity(capture: Capture, frames: int = INIT_FRAMES) -> float:
    """The intensity at which an object of mean albedo 0.5 renders the frames' mean object
    radiance: per frame I = pi L / (rho cos) r^2, L the mean radiance inside the mask, r the
    camera's distance to the object's centre less 2/3 of its radius (the mask's equivalent
    disc at that distance), cos = 2/3; the median over up to ``frames`` frames."""
    centre, _ = capture.bounds_hint()
    picks = np.unique(np.linspace(0, len(capture.frames) - 1, min(frames, len(capture.frames))).round().astype(int))
    values = []
    for i in picks:
        frame = capture.frames[int(i)]
        image = capture.camera_response.radiance(read_linear_rgb(frame.image))
        inside = (read_mask(frame.mask) > 0.5) if frame.mask else (image.max(-1) > 0)
        if not inside.any():
            continue
        cam = frame.camera
        d = float(np.linalg.norm(cam.centre - centre))
        radius = d * math.sqrt(inside.sum() / math.pi) / (0.5 * (cam.fx + cam.fy))
        r = max(d - MEAN_COSINE * radius, 0.1 * d)
        values.append(math.pi * float(image[inside].mean()) * r * r / (ALBEDO_CONVENTION * MEAN_COSINE))
    return float(np.median(values)) if values and np.median(values) > 0 else 1.0


class Flash(LightingModel):
    """The fitted flash (backend.lighting.base.LightingModel).

    Args:
        capture: the capture it lights: its frames' light lists follow ``latent``.
        latent: log intensity, (1,) or (3,) for RGB.
        initial: the starting intensity (W/sr) ``restart`` goes back to; None: the latent's.
    """

    lr: float = 0.1  # Adam step on the log intensity

    def __init__(self, capture: Capture, latent, initial: float | None = None):
        self.capture = capture
        self.scales: list[float] = []  # the convention's rescaling factors, one per stage
        self.initial_value = initial
        self.restarts = 0
        self.latent = latent

    @classmethod
    def initial(cls, capture: Capture, rgb: bool = False) -> "Flash":
        """The flash at ``initial_intensity``; ``rgb``: one latent per channel."""
        value = initial_intensity(capture)
        return cls(capture, np.full(3 if rgb else 1, math.log(value), np.float32), value)

    # -- the light ------------------------------------------------------------------------------
    @property
    def latent(self) -> np.ndarray:
        """Log intensity; setting it places the new flash in every frame."""
        return self._latent

    @latent.setter
    def latent(self, value) -> None:
        self._latent = np.asarray(value, np.float32).reshape(-1).copy()
        place(self.capture, self.rgb_intensity)

    @property
    def rgb_intensity(self) -> np.ndarray:
        """The intensity per channel, W/sr."""
        return np.broadcast_to(np.exp(self._latent.astype(np.float64)), (3,)).copy()

    @property
    def intensity(self) -> float | list[float]:
        """The fitted intensity, W/sr: one number, or RGB."""
        values = [round(float(x), 6) for x in np.exp(self._latent.astype(np.float64))]
        return values[0] if len(values) == 1 else values

    def environment(self) -> None:
        """No environment: the flash is the only light."""

    def at_stage(self, stage: str) -> bool:
        """One parameter at every stage: never changes."""
        return False

    def restart(self, capture: Capture | None = None) -> None:
        """Back to the initial intensity, to be fitted again (the relight on the final surface)."""
        if self.initial_value is not None:
            self.latent = np.full(len(self._latent), math.log(self.initial_value), np.float32)
        self.restarts += 1

    def normalise(self, material) -> float:
        """The scale convention (backend.lighting.convention): albedo x s, intensity / s.
        Returns s."""
        s = normalise_albedo(material, self.albedo_scale)
        self.latent = self._latent - np.float32(math.log(s))
        self.scales.append(round(s, 6))
        return s

    # -- a run's files, state and report -----------------------------------------------------------
    def save(self, folder: Path) -> None:
        """Nothing to write: the intensity is in the run's state and report."""

    def state(self) -> dict:
        """The log intensity (a flash writes no file)."""
        return {"latent": [float(x) for x in self._latent]}

    def restore(self, state: dict) -> None:
        """A resumed run: the intensity it had reached."""
        if state.get("latent"):
            self.latent = state["latent"]

    def report(self) -> dict:
        """report.json ``lighting``: the intensity (W/sr) under the convention, its start and rescalings."""
        return {"model": "flash", "intensity": self.intensity, "units": "W/sr",
                "parameterisation": "a point light at each camera centre, radiance falling off as 1/r^2; "
                                    "intensity = exp(latent), fitted with the material",
                "rgb": len(self._latent) == 3, "initial_intensity": self.initial_value,
                "scale_convention": CONVENTION, "albedo_scales": self.scales, "restarts": self.restarts}

    def event(self) -> dict:
        """The ``lighting`` event's fields (docs/protocol.md)."""
        return {"model": "flash", "intensity": self.intensity, "scale_convention": CONVENTION,
                "albedo_scale": self.scales[-1] if self.scales else None}

    def fit(self) -> "FlashFit":
        return FlashFit(self)


class FlashFit(LightingFit):
    """The flash's share of a material stage's Adam (backend.lighting.base.LightingFit): its
    log intensity, applied through the renderer's light scale (the fitted intensity over the
    one the frames' lights carry) before every render; no prior."""

    NAME = "flash"

    def __init__(self, flash: Flash):
        import drjit as dr
        import mitsuba as mi  # here: the model's maths and its report need no Mitsuba

        self.dr, self.mi = dr, mi
        self.flash = flash

    @property
    def lr(self) -> float:
        return self.flash.lr

    def present(self, renderer) -> bool:
        return getattr(renderer, "n_lights", 0) > 0

    def prepare(self, renderer, images, weights, views=None) -> None:
        """The intensity that renders ``images`` best (weighted squared error, the fit's
        ``weights``) with the material as it is, in closed form: a render R at the current
        intensity scaled by k gives k = sum w R T / sum w R^2 (per channel for RGB), from up
        to ``SOLVE_VIEWS`` of the ``views``."""
        self.reset(renderer)
        pool = list(range(len(images))) if views is None else list(views)
        num, den = np.zeros(3), np.zeros(3)
        for v in pool[:: max(1, math.ceil(len(pool) / SOLVE_VIEWS))]:
            rendered = renderer.render_numpy(v, seed=7919 + v).astype(np.float64)[..., :3]
            w = np.asarray(weights[v], np.float64)[..., None]
            num += (w * rendered * np.asarray(images[v], np.float64)[..., :3]).sum((0, 1))
            den += (w * rendered * rendered).sum((0, 1))
        if len(self.flash.latent) == 3:
            k = num / np.maximum(den, 1e-30)
        else:
            k = np.array([num.sum() / max(den.sum(), 1e-30)])
        if np.all(np.isfinite(k)) and np.all(k > 0) and np.all(den > 0):
            self.flash.latent = self.flash.latent + np.log(k).astype(np.float32)
            self.reset(renderer)

    def initial(self):
        return self.mi.Float(self.flash.latent)

    def apply(self, renderer, latent) -> None:
        """Light scale exp(latent - the flash's latent): 1 at the current intensity."""
        dr, mi = self.dr, self.mi
        scale = dr.exp(latent - mi.Float(self.flash.latent))
        if dr.width(scale) == 3:
            renderer.set_light_scale(mi.Color3f(*(dr.gather(mi.Float, scale, mi.UInt32(c)) for c in range(3))))
        else:
            renderer.set_light_scale(mi.Color3f(scale, scale, scale))

    def penalty(self, latent):
        """No prior on the intensity."""
        return self.mi.Float(0.0)

    def finish(self, renderer, latent) -> None:
        self.flash.latent = np.array(self.dr.detach(latent), np.float32)
        self.reset(renderer)

    def reset(self, renderer) -> None:
        """The renderer back to the frames' lights, which carry the flash's current intensity."""
        renderer.set_light_scale(None)
