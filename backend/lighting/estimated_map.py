"""The environment map fitted with the material (``--lighting estimate`` and ``rig``).

The map is a low-resolution equirectangular HDR image in Blender's World convention
(``capture.model.Environment``, rotation 0), texel = exp(latent) so it stays positive, with a
smoothness prior on neighbouring latents (longitude wrapping), coarse to fine (``RESOLUTIONS``:
one step per material stage reached). The material stages fit it by Adam with the material
(``EnvironmentFit``); geometry steps render with it and leave it fixed; after each stage the
scale convention rescales it with the albedo (backend.lighting.convention; the colour is left
to the fit). ``frame`` "camera" (``--lighting rig``) fixes the map to each view's camera instead
of the world: lamps on a camera rig, which turn with the view.

It starts from the frames' background outside the masks (the environment seen along the
camera rays), else a uniform grey, at the level at which an albedo of ``ALBEDO_CONVENTION``
renders the object as bright as the frames show it: a background is often a table or a wall,
far darker than the lamps that light the object, which an albedo bounded by 1 cannot make up
for. A rig's map starts uniform: the background the frames show is the world's, not the rig's."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..capture.images import area_resize, read_linear_rgb, read_mask, write_image
from ..capture.model import Capture, Environment
from .base import LightingFit, LightingModel
from .convention import ALBEDO_CONVENTION, describe, normalise_albedo

RESOLUTIONS = ((16, 8), (32, 16), (64, 32))  # (width, height): constant, diffuse, specular stage
STAGE_RESOLUTION = {"constant": 0, "diffuse": 1, "specular": 2, "done": 2}
CONVENTION = describe("map")
INIT_SIZE = 64  # long side of the frames read for the initial map
BACKGROUND_LEVEL = 1e-4  # a background pixel this dark is black (a premultiplied or masked frame)
BACKGROUND_SHARE = 0.05  # a frame whose background is black but for this share shows none (edge leaks)
FILENAME = "environment.exr"


def directions(width: int, height: int) -> np.ndarray:
    """World direction (Z up) of each texel centre, (height, width, 3) (Blender's lookup inverted:
    u = 0.5 - atan2(y, x) / 2pi, v = acos(z) / pi, v = 0 the top row)."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    phi = 2 * np.pi * (0.5 - u)[None, :]
    theta = np.pi * v[:, None]
    return np.stack(np.broadcast_arrays(np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                                        np.cos(theta) + 0 * phi), -1)


def texel_of(d: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of the texel a world direction (N, 3) looks up."""
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    u = (0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(d[:, 2], -1, 1)) / np.pi
    return np.minimum((v * height).astype(int), height - 1), np.minimum((u * width).astype(int), width - 1)


def background_samples(capture: Capture, size: int = INIT_SIZE):
    """World directions and radiance of the background pixels (outside the masks) of frames that
    show a background, and the mean radiance of the object pixels: (dirs (N, 3), rgb (N, 3),
    mean (3,), None when no mask covers any pixel)."""
    dirs, rgbs, inside = [], [], []
    for frame in capture.frames:
        cam = frame.camera
        f = min(1.0, size / max(cam.width, cam.height))
        w, h = max(1, round(cam.width * f)), max(1, round(cam.height * f))
        image = area_resize(capture.camera_response.radiance(read_linear_rgb(frame.image)), w, h)
        mask = area_resize(read_mask(frame.mask), w, h) if frame.mask else None
        if mask is None:
            continue
        obj = mask > 0.5
        if obj.any():
            inside.append(image[obj].mean(0))
        back = mask < 0.02
        if not back.any() or float(np.mean(image[back].max(-1) > BACKGROUND_LEVEL)) < BACKGROUND_SHARE:
            continue  # black outside the mask (rendered without a background, or premultiplied) but for a few
            # pixels where the object's anti-aliased edge leaks past a mask drawn a little tight
        ys, xs = np.nonzero(back)
        sx, sy = w / cam.width, h / cam.height
        gl = np.stack([(xs + 0.5 - cam.cx * sx) / (cam.fx * sx), -(ys + 0.5 - cam.cy * sy) / (cam.fy * sy),
                       -np.ones(len(xs))], -1)
        dirs.append(gl @ cam.camera_to_world[:3, :3].T)
        rgbs.append(image[back])
    mean = np.mean(inside, 0) if inside else None
    if not dirs:
        return np.zeros((0, 3)), np.zeros((0, 3)), mean
    return np.concatenate(dirs), np.concatenate(rgbs), mean


def sphere_mean(pixels: np.ndarray) -> np.ndarray:
    """Solid-angle weighted mean per channel of an equirectangular map (height, width, 3)."""
    h, w = pixels.shape[:2]
    weight = np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None, None]
    return (pixels * weight).sum((0, 1)) / (weight.sum() * w)


def initial_map(capture: Capture, width: int, height: int,
                background: bool = True) -> tuple[np.ndarray, str, float, float]:
    """The starting map (height, width, 3), where it came from ("background" or "uniform"), the
    share of texels the background showed and the factor the background was scaled by.

    Level: a diffuse object of albedo a under a map of mean radiance L shows about a x L (exactly
    so under a uniform map, less where it shades itself), so the map's solid-angle mean
    luminance is set to the object's mean brightness / ``ALBEDO_CONVENTION``; the background
    keeps its pattern and colour. Without object pixels the background keeps its level (1) and
    the grey is 0.5. Unseen texels take the mean of the seen ones. ``background`` False: the
    uniform grey at that level whatever the frames show."""
    dirs, rgb, object_mean = background_samples(capture)
    if not background:
        dirs = dirs[:0]
    level = 0.25 if object_mean is None else max(float(np.mean(object_mean)), 1e-3)
    grey = np.full(3, level / ALBEDO_CONVENTION)
    if len(dirs) == 0:
        return np.tile(grey, (height, width, 1)).astype(np.float32), "uniform", 0.0, 1.0
    rows, cols = texel_of(dirs, width, height)
    index = rows * width + cols
    count = np.bincount(index, minlength=width * height).astype(np.float64)
    sums = np.stack([np.bincount(index, rgb[:, c], minlength=width * height) for c in range(3)], -1)
    seen = count > 0
    pixels = np.empty((width * height, 3))
    pixels[seen] = sums[seen] / count[seen, None]
    pixels[~seen] = pixels[seen].mean(0)
    floor = 1e-3 * max(float(pixels.mean()), 1e-6)
    pixels = np.maximum(pixels, floor).reshape(height, width, 3)
    scale = 1.0 if object_mean is None else float(grey[0] / max(float(sphere_mean(pixels).mean()), 1e-12))
    return (pixels * scale).astype(np.float32), "background", float(seen.mean()), scale


def upsample(latent: np.ndarray, width: int, height: int) -> np.ndarray:
    """A latent map resampled (bilinear, longitude wrapping) to ``width`` x ``height``."""
    h0, w0, _ = latent.shape
    if (w0, h0) == (width, height):
        return latent
    x = (np.arange(width) + 0.5) * w0 / width - 0.5
    y = np.clip((np.arange(height) + 0.5) * h0 / height - 0.5, 0, h0 - 1)
    x0 = np.floor(x).astype(int)
    fx = (x - x0)[None, :, None]
    y0 = np.minimum(np.floor(y).astype(int), h0 - 1)
    y1 = np.minimum(y0 + 1, h0 - 1)
    fy = (y - y0)[:, None, None]
    a, b = x0 % w0, (x0 + 1) % w0
    top = latent[y0][:, a] * (1 - fx) + latent[y0][:, b] * fx
    bottom = latent[y1][:, a] * (1 - fx) + latent[y1][:, b] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


class EstimatedEnvironment(LightingModel):
    """The fitted map (backend.lighting.base.LightingModel).

    Args:
        latent: (height, width, 3) log radiance.
        path: where the map is written (RUN/environment.exr).
        source: where the start came from: "background", "uniform" or "resumed".
        seen: share of texels the frames' background showed.
        background_scale: the factor ``initial_map`` scaled the background by.
        frame: "world", or "camera" (fixed to each view's camera: ``--lighting rig``).
    """

    smoothness: float = 0.02  # x mean squared difference of neighbouring latents
    lr: float = 0.15  # Adam step on the latents: a sun some 20x the map's mean is 3 log units up

    def __init__(self, latent: np.ndarray, path: Path, source: str = "uniform", seen: float = 0.0,
                 background_scale: float = 1.0, frame: str = "world"):
        self.latent = np.asarray(latent, np.float32)
        self.path = Path(path)
        self.source, self.seen = source, seen
        self.background_scale = background_scale
        self.level = 0  # index into RESOLUTIONS
        self.frame = frame
        self.scales: list[float] = []  # the convention's rescaling factors, one per stage
        self.restarts = 0

    @classmethod
    def initial(cls, capture: Capture, path: Path, frame: str = "world") -> "EstimatedEnvironment":
        """The start ``initial_map`` gives at the coarsest resolution (uniform for a rig's map)."""
        width, height = RESOLUTIONS[0]
        pixels, source, seen, scale = initial_map(capture, width, height, background=frame == "world")
        return cls(np.log(pixels), path, source, seen, scale, frame)

    @classmethod
    def load(cls, path: Path, level: int = 0, frame: str = "world") -> "EstimatedEnvironment":
        """The map a resumed run wrote (RUN/environment.exr)."""
        pixels = read_linear_rgb(path)
        out = cls(np.log(np.maximum(pixels, 1e-8)), path, "resumed", frame=frame)
        out.level = level
        return out

    # -- the map ---------------------------------------------------------------------------------
    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) in texels."""
        return self.latent.shape[1], self.latent.shape[0]

    @property
    def pixels(self) -> np.ndarray:
        """The map's radiance, (height, width, 3) float32."""
        return np.exp(self.latent).astype(np.float32)

    def environment(self) -> Environment:
        """The capture's lighting now: the current map (in memory), strength 1, rotation 0."""
        return Environment(self.path, 1.0, 0.0, "estimated", pixels=self.pixels, frame=self.frame)

    def mean_radiance(self) -> list[float]:
        """Solid-angle weighted mean radiance per channel (the map's average over the sphere)."""
        return [float(x) for x in sphere_mean(self.pixels)]

    def at_stage(self, stage: str) -> bool:
        """Coarse to fine: the resolution of the material stage about to run (never coarser);
        True when it changed."""
        level = max(self.level, STAGE_RESOLUTION.get(stage, 0))
        if level == self.level and self.resolution == RESOLUTIONS[level]:
            return False
        self.level = level
        self.latent = upsample(self.latent, *RESOLUTIONS[level])
        return True

    def restart(self, capture: Capture) -> None:
        """Back to the initial map at the coarsest resolution, to be fitted again (the relight
        on the final surface: backend.optimize.relight)."""
        width, height = RESOLUTIONS[0]
        pixels, self.source, self.seen, self.background_scale = initial_map(capture, width, height,
                                                                            background=self.frame == "world")
        self.latent, self.level = np.log(pixels).astype(np.float32), 0
        self.restarts += 1

    def rescale(self, factor: float) -> None:
        """The map's radiance times ``factor``."""
        self.latent = self.latent + np.float32(np.log(factor))

    def normalise(self, material) -> float:
        """The scale convention, after a stage: map and material rescaled together so the mean
        albedo is ``ALBEDO_CONVENTION`` (specular scaled with the albedo; renders unchanged
        while no value clips at 1). A fitted light factor is folded into the map. Returns the
        factor the albedo was multiplied by."""
        light = float(getattr(material, "light_factor", 1.0) or 1.0)
        if light != 1.0:
            self.rescale(light)
            material.light_factor = 1.0
        s = normalise_albedo(material, self.albedo_scale)
        self.rescale(1.0 / s)
        self.scales.append(round(s, 6))
        return s

    def write(self, path: Path | None = None) -> Path:
        """The map as an EXR (equirectangular, Blender's World convention), atomically."""
        path = Path(path or self.path)
        write_image(path, self.pixels)
        return path

    def save(self, folder: Path) -> Path:
        """The map into a run folder (``folder``/environment.exr)."""
        return self.write(Path(folder) / FILENAME)

    def state(self) -> dict:
        """The coarse-to-fine level (the map is in its file)."""
        return {"level": self.level}

    def restore(self, state: dict) -> None:
        """A resumed run: the coarse-to-fine level (the map itself is read from its file)."""
        self.level = int(state.get("level", 0))

    def report(self) -> dict:
        """report.json ``lighting``: the map's file, resolution, start, rescalings and mean radiance."""
        width, height = self.resolution
        return {"model": "environment map (estimated)", "file": FILENAME, "resolution": [width, height],
                "parameterisation": "texel = exp(latent), smoothness prior on neighbouring latents",
                "smoothness": self.smoothness, "frame": self.frame, "initial": self.source,
                "background_coverage": round(self.seen, 4),
                "background_scale": round(self.background_scale, 6),
                "scale_convention": CONVENTION, "albedo_scales": self.scales, "restarts": self.restarts,
                "mean_radiance": [round(x, 6) for x in self.mean_radiance()]}

    def event(self) -> dict:
        """The ``lighting`` event's fields (docs/protocol.md)."""
        report = self.report()
        return {"model": "estimate", "frame": self.frame, "resolution": report["resolution"],
                "initial": report["initial"],
                "scale_convention": report["scale_convention"], "mean_radiance": report["mean_radiance"],
                "albedo_scale": self.scales[-1] if self.scales else None}

    def fit(self) -> "EnvironmentFit":
        return EnvironmentFit(self)


class EnvironmentFit(LightingFit):
    """The map's share of a material stage's Adam (backend.lighting.base.LightingFit): its
    latent, flattened, written as exp(latent) into the scene's ``environment.data`` before
    every render, with the smoothness prior as its penalty."""

    KEY = "environment.data"
    NAME = "environment"

    def __init__(self, estimate: EstimatedEnvironment):
        import drjit as dr
        import mitsuba as mi  # here: the rest of the module (the map's maths, its files) needs no Mitsuba

        self.dr, self.mi = dr, mi
        self.estimate = estimate
        h, w, _ = estimate.latent.shape
        # Mitsuba's envmap data carries one wrapped column on each side: (h, w + 2, 3)
        cols = np.concatenate([[w - 1], np.arange(w), [0]])
        index = (np.arange(h)[:, None, None] * w + cols[None, :, None]) * 3 + np.arange(3)[None, None, :]
        self.index = mi.UInt32(index.astype(np.uint32).ravel())
        self.shape = (h, w + 2, 3)
        right = (np.arange(h)[:, None] * w + (np.arange(w)[None, :] + 1) % w)
        down = np.minimum(np.arange(h)[:, None] + 1, h - 1) * w + np.arange(w)[None, :]
        here = np.arange(h)[:, None] * w + np.arange(w)[None, :]
        pairs = np.concatenate([np.stack([here, right], -1).reshape(-1, 2),
                                np.stack([here[:-1], down[:-1]], -1).reshape(-1, 2)])
        self.pairs = [mi.UInt32((pairs[:, k, None] * 3 + np.arange(3)).astype(np.uint32).ravel()) for k in (0, 1)]

    @property
    def lr(self) -> float:
        return self.estimate.lr

    def present(self, renderer) -> bool:
        return self.KEY in renderer.params

    def prepare(self, renderer, images, weights, views=None) -> None:
        """No closed form: the map starts where the last stage left it."""

    def initial(self):
        return self.mi.Float(self.estimate.latent.ravel())

    def apply(self, renderer, latent) -> None:
        """Write exp(latent) into the scene (per view: a backward pass uses up the graph)."""
        dr, mi = self.dr, self.mi
        data = dr.gather(mi.Float, dr.exp(latent), self.index)
        renderer.params[self.KEY] = mi.TensorXf(data, self.shape)
        renderer.params.update()

    def penalty(self, latent):
        """``smoothness`` x the mean squared difference of neighbouring latents (longitude wrapping)."""
        dr, mi = self.dr, self.mi
        a, b = (dr.gather(mi.Float, latent, p) for p in self.pairs)
        return self.estimate.smoothness * dr.mean(dr.square(a - b))

    def finish(self, renderer, latent) -> None:
        self.estimate.latent = np.array(self.dr.detach(latent), np.float32).reshape(self.estimate.latent.shape)
        self.reset(renderer)

    def reset(self, renderer) -> None:
        """The scene's map set to the estimate's current latent (no gradients)."""
        with self.dr.suspend_grad():
            self.apply(renderer, self.mi.Float(self.estimate.latent.ravel()))
