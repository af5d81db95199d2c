"""The one place a material model is chosen: by ``--material`` for a new run, by the kind
stored in the saved state for a resumed one."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .base import Material
from .constant import ConstantMaterial
from .model import MeshColorMaterial

MODELS: dict[str, type[Material]] = {"constant": ConstantMaterial, "meshcolors": MeshColorMaterial}


def kind_for(spec: str) -> str:
    """The model ``--material spec`` asks for: mesh colors for ``staged``, else constants."""
    return "meshcolors" if spec == "staged" else "constant"


def create(spec: str, mesh=None, resolution: int = 4, labels=None, n_materials: int | None = None) -> Material:
    """A new material for ``--material spec``: mesh colors on ``mesh`` (with per-face
    ``labels``) for ``staged``; else the constant model (``auto`` or ``known:...``)."""
    if kind_for(spec) == "meshcolors":
        return MeshColorMaterial(mesh, resolution, labels, n_materials)
    return ConstantMaterial.from_spec(spec)


def saved_kind(path: str | Path) -> str:
    """The model of a saved material: its stored ``kind``; saves made before the kind was
    stored are mesh colors when they hold a ``resolution``."""
    with np.load(path) as data:
        if "kind" in data.files:
            return str(data["kind"])
        return "meshcolors" if "resolution" in data.files else "constant"


def load(path: str | Path, expected: str | None = None, folder=None) -> Material:
    """The saved material at ``path``; with ``expected`` (a kind), an InputError when the run
    was made with the other model."""
    kind = saved_kind(path)
    if expected is not None and kind != expected:
        staged = kind == "meshcolors"
        raise InputError(folder, f"the run was made {'with' if staged else 'without'} --material staged",
                         "resume with the options the run was started with")
    return MODELS[kind].load(path)
