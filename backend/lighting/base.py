"""The interface of lighting fitted with the material (as ``material.base`` is for the materials).

Two roles. A ``LightingModel`` is the lighting a run fits and keeps between material stages
(``Appearance.lighting``): ``EstimatedEnvironment`` (backend.lighting.estimated_map, ``--lighting
estimate`` and ``rig``) and ``Flash`` (backend.lighting.flash, ``--lighting flash``). A
``LightingFit`` is one material stage's share of the Adam fit (``material.stages.fit``): one
latent beside the material's, written into the scene before every render. ``EnvironmentFit``
and ``FlashFit`` are the models' fits; ``LightFactor`` (backend.lighting.light_factor) fits
the brightness of a captured map, whose model is the material's ``light_factor``.

Every latent is a log scale of the light: the light at latent + c is e^c times the light at
latent, so a render, linear in the light, is e^c times brighter. Images fix only albedo x
light; the level is settled after each stage by the scale convention (backend.lighting.convention),
not by the fit's prior."""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path


class LightingFit(ABC):
    """A fitted light's latent in a material stage's Adam.

    Lifecycle within ``material.stages.fit``: ``present`` (else the fit takes no part),
    ``prepare``, ``initial``; then per iteration ``apply`` before each view's render and
    ``penalty`` once; ``finish`` after the last. ``renderer`` is the stage's
    ``SceneRenderer`` throughout; latents are Dr.Jit ``mi.Float`` arrays.

    Attributes:
        NAME: the latent's key in the stage's optimiser (distinct from the material's
            channel names).
    """

    NAME = ""

    @property
    @abstractmethod
    def lr(self) -> float:
        """Adam's step on the latent, in log units (a step of 0.1 changes the light by about
        10 %); the stage decays it with the material's step."""

    @abstractmethod
    def present(self, renderer) -> bool:
        """Whether the renderer's scene has what this fit drives (an environment map, point
        lights); a fit not present leaves the stage and the scene alone."""

    @abstractmethod
    def prepare(self, renderer, images, weights, views=None) -> None:
        """Before Adam: the start solved from the stage's data, where the model has a closed
        form, else the model's current light (the scene left rendering it).

        Args:
            images: target images, linear RGB (H, W, 3), one per renderer view.
            weights: per-pixel weights (H, W), one per view, as the stage's loss weighs them.
            views: the views the stage fits (None: all).
        """

    @abstractmethod
    def initial(self):
        """The latent's start (``mi.Float``): the log of the model's current light."""

    @abstractmethod
    def apply(self, renderer, latent) -> None:
        """Write the light of ``latent`` into the scene, keeping its AD graph (called before
        every render: each view's backward pass uses up the graph)."""

    @abstractmethod
    def penalty(self, latent):
        """The prior added to the stage's loss (``mi.Float``, dimensionless; 0 when none).
        It does not change under latent + c: the level is the scale convention's."""

    @abstractmethod
    def finish(self, renderer, latent) -> None:
        """Take the optimised ``latent`` (detached) into the model and leave the scene
        rendering it, as ``reset``."""

    @abstractmethod
    def reset(self, renderer) -> None:
        """The scene set to the model's current light, without gradients."""


class LightingModel(ABC):
    """The lighting a run fits with the material, kept between stages.

    Attributes:
        latent: its parameters, a log scale of the light (numpy float32); the relight copies
            it and puts it back (backend.optimize.relight).
        lr: Adam's step on ``latent`` in its fits.
        albedo_scale: what sets the albedo's scale in ``normalise``
            (backend.lighting.convention.AlbedoScale; None: the mean-albedo default).
    """

    latent: "np.ndarray"
    lr: float
    albedo_scale = None

    @abstractmethod
    def fit(self) -> LightingFit:
        """Its share of one material stage's Adam, on the model's current values."""

    @abstractmethod
    def environment(self):
        """The capture's environment under this lighting (``capture.model.Environment``, the
        current map in memory), or None when it lights by point lights alone."""

    @abstractmethod
    def at_stage(self, stage: str) -> bool:
        """Adapt to the material stage about to run (``constant``, ``diffuse``, ``specular``:
        coarse to fine where the model has resolutions); True when the parameters changed."""

    @abstractmethod
    def normalise(self, material) -> float:
        """The scale convention after a stage (backend.lighting.convention): albedo and
        specular x s so the mean albedo is ``ALBEDO_CONVENTION``, the light / s; renders unchanged while no
        value clips. Returns s."""

    @abstractmethod
    def restart(self, capture) -> None:
        """Back to the initial values the capture gives, to be fitted again (the relight on
        the final surface)."""

    @abstractmethod
    def save(self, folder: Path) -> None:
        """Write its files into the run folder (atomically; nothing where the state holds
        all of it)."""

    @abstractmethod
    def state(self) -> dict:
        """What a resumed run needs beside the files, JSON-serialisable."""

    @abstractmethod
    def restore(self, state: dict) -> None:
        """Take back a resumed run's ``state()``."""

    @abstractmethod
    def report(self) -> dict:
        """The fitted lighting for report.json ``lighting`` (its ``model`` names it)."""

    @abstractmethod
    def event(self) -> dict:
        """The ``lighting`` event's fields (docs/protocol.md)."""
