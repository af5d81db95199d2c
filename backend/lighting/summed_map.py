"""A world-fixed and a camera-fixed environment map, summed (``--lighting world+rig``).

Real captures mix light fixed to the room (windows, ceiling lamps) with light that turns with
the camera (lamps on a rig, a flash, the operator): neither map alone can show both. The model
is two low-resolution maps in Blender's World convention (backend.lighting.estimated_map, each
its own ``EstimatedEnvironment``, coarse to fine together): the radiance arriving from world
direction d in view i is

    L_i(d) = W(d) + R(A_i^T d)

with W the world map, R the rig map in the rig frame of ``Environment.rig_axes`` (A_i, from view
i's camera). A render is linear in the light, so this is exactly the sum of the two single-map
renders, at the cost of one: before each view's render the scene's one envmap is set to W plus
R resampled into the world frame for that view (``SummedMaps``: bilinear in R, longitude
wrapping, at W's texel centres). Both maps are fitted by Adam with the material
(``SummedFit``: the two latents side by side, each with the single map's smoothness prior);
the scale convention rescales both. A light that is the same in every direction is the same in
either frame: how a uniform part splits between the maps is not fixed by the images, and
changes no render.

Files: RUN/environment.exr (the world map) and RUN/environment_rig.exr (the rig map);
report.json ``lighting`` names the model ``environment map (estimated)``, ``frame``
``world+camera``, ``rig_file``. Each map starts at half the single map's level: the world map
from the frames' background, the rig map uniform (the background the frames show is the
world's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..capture.images import read_linear_rgb
from ..capture.model import Capture, Environment
from .base import LightingFit, LightingModel
from .convention import normalise_albedo
from .estimated_map import FILENAME, STAGE_RESOLUTION, EstimatedEnvironment, EnvironmentFit, directions

FRAME = "world+camera"  # Environment.frame of the summed model
RIG_FILENAME = "environment_rig.exr"
START_SHARE = 0.5  # each map starts at this share of the single map's level
# the finest stage whose resolution the maps take (estimated_map.RESOLUTIONS): two maps hold twice
# the texels of one, which the frames pin down less well, so they stop at the diffuse stage's
FINEST_STAGE = "diffuse"


def rig_lookup(width: int, height: int, rig_width: int, rig_height: int,
               camera_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every texel of a ``width`` x ``height`` world map, the 4 texels of a ``rig_width`` x
    ``rig_height`` rig map and their bilinear weights at d_rig = A^T d (d the world texel's
    centre, A = ``Environment.rig_axes``): (index (h*w, 4) into the rig map's texels, row major;
    weights (h*w, 4), rows summing to 1). Longitude wraps; latitude clamps at the poles."""
    d = directions(width, height).reshape(-1, 3)
    local = d @ Environment.rig_axes(camera_to_world)  # rows: A^T d
    u = (0.5 - np.arctan2(local[:, 1], local[:, 0]) / (2 * np.pi)) % 1.0
    v = np.arccos(np.clip(local[:, 2], -1, 1)) / np.pi
    x = u * rig_width - 0.5
    y = np.clip(v * rig_height - 0.5, 0, rig_height - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.minimum(np.floor(y).astype(int), rig_height - 1)
    y1 = np.minimum(y0 + 1, rig_height - 1)
    fx, fy = x - x0, y - y0
    a, b = x0 % rig_width, (x0 + 1) % rig_width
    index = np.stack([y0 * rig_width + a, y0 * rig_width + b, y1 * rig_width + a, y1 * rig_width + b], -1)
    weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], -1)
    return index, weight


def composed(world: np.ndarray, rig: np.ndarray, camera_to_world: np.ndarray) -> np.ndarray:
    """The one world-frame map (h, w, 3) that lights view ``camera_to_world`` as ``world`` plus
    ``rig`` turned with that camera (numpy; the renderer does the same in Dr.Jit)."""
    h, w, _ = world.shape
    index, weight = rig_lookup(w, h, rig.shape[1], rig.shape[0], camera_to_world)
    flat = rig.reshape(-1, 3)
    return (world.reshape(-1, 3) + (flat[index] * weight[..., None]).sum(1)).reshape(h, w, 3).astype(np.float32)


def rig_pixels(env: Environment) -> np.ndarray:
    """The rig map of a summed ``env``: in memory, else read from ``env.rig_path``."""
    if env.rig_pixels is not None:
        return np.asarray(env.rig_pixels, np.float32)
    return read_linear_rgb(env.rig_path)


class SummedMaps:
    """A SceneRenderer's summed map: before each view's render the scene's envmap data is set
    to the world map plus the rig map turned with that view's camera.

    ``sources`` is (world texels, rig texels) as flat Dr.Jit arrays (h*w*3, row-major RGB);
    a fit sets them attached to AD before every render (``SummedFit.apply``), else they hold
    the environment's maps."""

    KEY = "environment.data"

    def __init__(self, env: Environment, cameras, world_pixels: np.ndarray | None = None):
        import drjit as dr
        import mitsuba as mi

        self.dr, self.mi = dr, mi
        world = np.asarray(world_pixels if world_pixels is not None else
                           (env.pixels if env.pixels is not None else read_linear_rgb(env.path)), np.float32)
        rig = rig_pixels(env)
        self.cameras = list(cameras)
        self._build(world.shape, rig.shape)
        self.sources = (mi.Float(world.ravel()), mi.Float(rig.ravel()))
        self.attached = False  # sources on AD: compose before every render
        self._view = None

    def _build(self, world_shape, rig_shape) -> None:
        """The envmap's layout and every view's rig lookups, for maps of these shapes (h, w, 3)."""
        mi = self.mi
        self.world_shape, self.rig_shape = tuple(world_shape), tuple(rig_shape)
        h, w, _ = world_shape
        cols = np.concatenate([[w - 1], np.arange(w), [0]])  # Mitsuba's data: one wrapped column each side
        layout = (np.arange(h)[:, None, None] * w + cols[None, :, None]) * 3 + np.arange(3)[None, None, :]
        self.layout = mi.UInt32(layout.astype(np.uint32).ravel())
        self.shape = (h, w + 2, 3)
        self.lookups = []
        for cam in self.cameras:
            index, weight = rig_lookup(w, h, rig_shape[1], rig_shape[0], cam.camera_to_world)
            self.lookups.append([(mi.UInt32((index[:, k, None] * 3 + np.arange(3)).astype(np.uint32).ravel()),
                                  mi.Float(np.repeat(weight[:, k], 3).astype(np.float32))) for k in range(4)])

    def set_sources(self, world, rig, attached: bool, world_shape=None, rig_shape=None) -> None:
        """The maps' texels from the next render on (shapes (h, w, 3) when they changed: a finer stage)."""
        if world_shape is not None and (tuple(world_shape) != self.world_shape or tuple(rig_shape) != self.rig_shape):
            self._build(world_shape, rig_shape)
        self.sources, self.attached, self._view = (world, rig), attached, None

    def write(self, renderer, view: int, params=None) -> None:
        """The scene's envmap set to view ``view``'s summed map (also in ``params``, the scene
        parameters a render routes gradients through, when they are a copy)."""
        if self._view == view and not self.attached:
            return
        dr, mi = self.dr, self.mi
        world, rig = self.sources
        texels = world
        for index, weight in self.lookups[view]:
            texels = texels + dr.gather(mi.Float, rig, index) * weight
        data = mi.TensorXf(dr.gather(mi.Float, texels, self.layout), self.shape)
        renderer.params[self.KEY] = data
        renderer.params.update()
        if params is not None and params is not renderer.params and self.KEY in params:
            params[self.KEY] = data
            params.update()
        self._view = view


class SummedEnvironment(LightingModel):
    """The two fitted maps (backend.lighting.base.LightingModel): ``world`` (fixed to the world)
    and ``rig`` (fixed to each view's camera), each an ``EstimatedEnvironment``."""

    frame = FRAME

    def __init__(self, world: EstimatedEnvironment, rig: EstimatedEnvironment):
        self.world, self.rig = world, rig
        self.lr = world.lr
        self.scales: list[float] = []

    @classmethod
    def initial(cls, capture: Capture, path: Path) -> "SummedEnvironment":
        """Each map at ``START_SHARE`` of the single map's start (the world's from the background,
        the rig's uniform), so their sum starts as bright as either alone would."""
        world = EstimatedEnvironment.initial(capture, path, "world")
        rig = EstimatedEnvironment.initial(capture, Path(path).with_name(RIG_FILENAME), "camera")
        world.rescale(START_SHARE)
        rig.rescale(START_SHARE)
        return cls(world, rig)

    @classmethod
    def load(cls, path: Path) -> "SummedEnvironment":
        """The maps a resumed run wrote (RUN/environment.exr and RUN/environment_rig.exr)."""
        path = Path(path)
        return cls(EstimatedEnvironment.load(path, frame="world"),
                   EstimatedEnvironment.load(path.with_name(RIG_FILENAME), frame="camera"))

    @staticmethod
    def files_exist(path: Path) -> bool:
        return Path(path).is_file() and Path(path).with_name(RIG_FILENAME).is_file()

    # the relight copies the latent and puts it back (backend.optimize.relight)
    @property
    def latent(self) -> np.ndarray:
        return np.concatenate([self.world.latent.ravel(), self.rig.latent.ravel()])

    @latent.setter
    def latent(self, value) -> None:
        n = self.world.latent.size
        value = np.asarray(value, np.float32)
        self.world.latent = value[:n].reshape(self.world.latent.shape)
        self.rig.latent = value[n:].reshape(self.rig.latent.shape)

    @property
    def level(self) -> int:
        return self.world.level

    @level.setter
    def level(self, value) -> None:
        self.world.level = self.rig.level = value

    def environment(self) -> Environment:
        """The capture's lighting now: the world map (``pixels``) and the rig map (``rig_pixels``)."""
        return Environment(self.world.path, 1.0, 0.0, "estimated", pixels=self.world.pixels, frame=FRAME,
                           rig_path=self.rig.path, rig_pixels=self.rig.pixels)

    def at_stage(self, stage: str) -> bool:
        """Coarse to fine, both maps together, no finer than ``FINEST_STAGE``'s resolution."""
        if STAGE_RESOLUTION.get(stage, 0) > STAGE_RESOLUTION[FINEST_STAGE]:
            stage = FINEST_STAGE
        changed = self.world.at_stage(stage)
        return self.rig.at_stage(stage) or changed

    def normalise(self, material) -> float:
        """The scale convention: as the single map's, both maps rescaled by the same factor."""
        light = float(getattr(material, "light_factor", 1.0) or 1.0)
        if light != 1.0:
            self.world.rescale(light)
            self.rig.rescale(light)
            material.light_factor = 1.0
        s = normalise_albedo(material, self.albedo_scale)
        self.world.rescale(1.0 / s)
        self.rig.rescale(1.0 / s)
        self.scales.append(round(s, 6))
        return s

    def restart(self, capture) -> None:
        self.world.restart(capture)
        self.rig.restart(capture)
        self.world.rescale(START_SHARE)
        self.rig.rescale(START_SHARE)

    def save(self, folder: Path) -> None:
        self.world.save(folder)
        self.rig.write(Path(folder) / RIG_FILENAME)

    def state(self) -> dict:
        return {"level": self.world.level}

    def restore(self, state: dict) -> None:
        self.level = int(state.get("level", 0))

    def report(self) -> dict:
        """report.json ``lighting``: the world map's fields, ``frame`` world+camera, the rig map's
        file, and each map's mean radiance."""
        out = self.world.report()
        rig = self.rig.report()
        out.update(frame=FRAME, file=FILENAME, rig_file=RIG_FILENAME, albedo_scales=self.scales,
                   mean_radiance=[round(a + b, 6) for a, b in zip(out["mean_radiance"], rig["mean_radiance"])],
                   world_mean_radiance=out["mean_radiance"], rig_mean_radiance=rig["mean_radiance"],
                   rig_resolution=rig["resolution"])
        return out

    def event(self) -> dict:
        report = self.report()
        return {"model": "estimate", "frame": FRAME, "resolution": report["resolution"], "initial": report["initial"],
                "scale_convention": report["scale_convention"], "mean_radiance": report["mean_radiance"],
                "rig_mean_radiance": report["rig_mean_radiance"],
                "albedo_scale": self.scales[-1] if self.scales else None}

    def fit(self) -> "SummedFit":
        return SummedFit(self)


class SummedFit(LightingFit):
    """Both maps' share of a material stage's Adam: one latent, the world map's texels then the
    rig map's, handed to the renderer's ``SummedMaps`` as exp(latent) before every render; the
    penalty is each map's smoothness prior."""

    NAME = "summed_environment"

    def __init__(self, model: SummedEnvironment):
        import drjit as dr
        import mitsuba as mi

        self.dr, self.mi = dr, mi
        self.model = model
        self.n = model.world.latent.size
        self.m = model.rig.latent.size
        self.world_index = mi.UInt32(np.arange(self.n, dtype=np.uint32))
        self.rig_index = mi.UInt32(np.arange(self.n, self.n + self.m, dtype=np.uint32))
        # the smoothness pairs of each map, the rig's offset past the world's texels
        self.parts = [(EnvironmentFit(model.world), 0), (EnvironmentFit(model.rig), self.n)]

    @property
    def lr(self) -> float:
        return self.model.lr

    def present(self, renderer) -> bool:
        return getattr(renderer, "summed", None) is not None

    def prepare(self, renderer, images, weights, views=None) -> None:
        """No closed form: the maps start where the last stage left them."""

    def initial(self):
        return self.mi.Float(self.model.latent)

    def apply(self, renderer, latent) -> None:
        dr, mi = self.dr, self.mi
        e = dr.exp(latent)
        renderer.summed.set_sources(dr.gather(mi.Float, e, self.world_index), dr.gather(mi.Float, e, self.rig_index),
                                    True, self.model.world.latent.shape, self.model.rig.latent.shape)

    def penalty(self, latent):
        dr, mi = self.dr, self.mi
        total = mi.Float(0.0)
        for part, offset in self.parts:
            a, b = (dr.gather(mi.Float, latent, p + offset) for p in part.pairs)
            total += part.estimate.smoothness * dr.mean(dr.square(a - b))
        return total

    def finish(self, renderer, latent) -> None:
        self.model.latent = np.array(self.dr.detach(latent), np.float32)
        self.reset(renderer)

    def reset(self, renderer) -> None:
        mi = self.mi
        renderer.summed.set_sources(mi.Float(self.model.world.pixels.ravel()), mi.Float(self.model.rig.pixels.ravel()),
                                    False, self.model.world.latent.shape, self.model.rig.latent.shape)
