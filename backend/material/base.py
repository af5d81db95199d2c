"""The interface every material model offers the reconstruction loop (as Mitsuba's
integrators share one base class): ``ConstantMaterial`` (material.constant) and
``MeshColorMaterial`` (material.model) implement it; ``material.factory`` picks one.

Channels: diffuse albedo (RGB), specular reflectance and roughness, each stored as latents z
with value lo + (hi - lo) sigmoid(z) (``CHANNELS``: name -> (width, lo, hi))."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry.mesh import Mesh

CHANNELS = {"albedo": (3, 0.0, 1.0), "specular": (1, 0.0, 1.0), "roughness": (1, 0.0, 1.0)}
NEUTRAL = {"albedo": 0.5, "specular": 0.1, "roughness": 0.5}  # a restarted material; display meshes' default


class Material:
    """Base class of the material models.

    Attributes:
        KIND: the model's name, stored in the saved state ("constant" or "meshcolors").
        field: what SurfaceBSDF reads (``lookup(si, active)`` and ``arrays()``).
        trainable: channel names the loop optimises (empty for a known material).
        light_factor: the environment brightness factor k the material was fitted under
            (scene scale = strength x k); 1 when the model does not fit one.
    """

    KIND = ""
    CHANNELS = CHANNELS
    light_factor = 1.0

    # -- values ----------------------------------------------------------------------------
    def values(self, name: str) -> np.ndarray:
        """Current values of channel ``name``, shape (n, width): one row per material for
        constants, one per sample for mesh colors."""
        raise NotImplementedError

    def set_values(self, name: str, values, kind: str | None = None) -> None:
        """Set channel ``name`` (broadcast to its shape); ``kind`` ("constant" or "colors")
        changes the channel's representation where the model has more than one."""
        raise NotImplementedError

    def disable(self, name: str) -> None:
        """Fix channel ``name`` at 0 and stop training it (the diffuse-only model for
        "specular")."""
        self.make_constant(name)
        self.set_values(name, np.zeros_like(self.values(name)))
        self.trainable = tuple(t for t in self.trainable if t != name)

    def make_constant(self, name: str) -> None:
        """Turn channel ``name`` into per-material constants (a no-op for constant models)."""

    def restart_specular(self) -> None:
        """The specular lobe back at its neutral start and trained again (held at 0 it would
        stay there: the reparameterising sigmoid is flat at its ends); roughness with it."""
        raise NotImplementedError

    # -- optimisation ----------------------------------------------------------------------
    def parameters(self) -> dict:
        """The latent Dr.Jit leaves read by ``field``, by channel name."""
        raise NotImplementedError

    def load_parameters(self, params: dict) -> None:
        """Take latents back (Dr.Jit or numpy arrays) for the named channels."""
        raise NotImplementedError

    def attach(self, scene_params):
        """Scene parameters through which ``mi.render`` routes the latents' gradients."""
        return scene_params

    # -- mesh changes ----------------------------------------------------------------------
    def on_subdivide(self, old_mesh: Mesh, new_mesh: Mesh) -> None:
        """Carry the material onto a 1-to-4 subdivision of ``old_mesh``."""

    def on_remesh(self, new_mesh: Mesh, old_mesh: Mesh | None = None, reset: bool = True) -> None:
        """After re-meshing or simplification: restart from neutral values (``reset``) or
        resample the old surface's values."""

    # -- outputs ---------------------------------------------------------------------------
    def display(self, mesh: Mesh) -> Mesh:
        """The snapshot mesh with per-vertex albedo, specular and roughness."""
        raise NotImplementedError

    def save(self, path: str | Path) -> None:
        """Write the material (npz, atomic) for --resume; the npz holds ``kind`` = KIND."""
        raise NotImplementedError

    @classmethod
    def load(cls, path: str | Path) -> "Material":
        raise NotImplementedError

    def summary(self) -> dict:
        """The material for report.json."""
        raise NotImplementedError
