"""The constant material model: one albedo (RGB), specular and roughness for the whole
surface, known (``known:R,G,B:SPEC:ROUGH``) or estimated (``auto``)."""

from __future__ import annotations

import io
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import fsio
from ..errors import InputError
from ..geometry.mesh import Mesh
from .base import CHANNELS, Material
from .field import squash

START = {"albedo": 0.5, "specular": 0.2, "roughness": 0.4}  # an estimated constant material's start


def _logit(value: float, lo: float, hi: float) -> float:
    t = np.clip((value - lo) / (hi - lo), 1e-4, 1 - 1e-4)
    return float(np.log(t) - np.log1p(-t))


def parse_spec(spec: str) -> tuple[list[float], float, float] | None:
    """None for an estimated material (``auto``, or ``staged`` whose mesh colors start from
    these constants); (albedo RGB, specular, roughness) for ``known:R,G,B:SPEC:ROUGH``."""
    if spec in ("auto", "staged"):
        return None
    fix = ("write --material auto, staged or known:ALBEDO_R,G,B:SPECULAR:ROUGHNESS, "
           "e.g. known:0.6,0.6,0.6:0.3:0.3")
    parts = spec.split(":")
    try:
        if parts[0] != "known" or len(parts) != 4:
            raise ValueError
        albedo = [float(x) for x in parts[1].split(",")]
        albedo = albedo * 3 if len(albedo) == 1 else albedo
        specular, roughness = float(parts[2]), float(parts[3])
    except ValueError:
        raise InputError(None, f"cannot read the material '{spec}'", fix) from None
    values = albedo + [specular, roughness]
    if len(albedo) != 3 or not all(np.isfinite(v) and 0 <= v <= 1 for v in values):
        raise InputError(None, f"material values must be 3 albedo values, specular and roughness in [0, 1] "
                         f"(got '{spec}')", fix)
    return albedo, specular, roughness


class LatentConstantField:
    """The material field of a constant material: its latents (Dr.Jit arrays of one value
    per channel) read through sigmoids, so gradients reach them and values stay in range."""

    def __init__(self, material: "ConstantMaterial"):
        self.material = material

    def arrays(self) -> dict:
        return self.material.parameters()

    def lookup(self, si, active):
        latents = self.material.latents
        out = []
        for name, (width, lo, hi) in CHANNELS.items():
            kind = mi.Color3f if width == 3 else mi.Float
            out.append(squash(dr.gather(kind, latents[name], 0), lo, hi))
        return tuple(out)


class ConstantMaterial(Material):
    """A known (fixed) or estimated constant albedo (RGB), specular and roughness."""

    KIND = "constant"

    def __init__(self, albedo=START["albedo"], specular: float = START["specular"],
                 roughness: float = START["roughness"], estimate: bool = True):
        self.latents: dict[str, mi.Float] = {}
        self._set_all({"albedo": albedo, "specular": specular, "roughness": roughness})
        self.trainable = tuple(CHANNELS) if estimate else ()
        self.field = LatentConstantField(self)

    @classmethod
    def from_spec(cls, spec: str) -> "ConstantMaterial":
        """``auto`` (estimated, starting from neutral values) or ``known:R,G,B:SPEC:ROUGH``."""
        known = parse_spec(spec)
        return cls() if known is None else cls(*known, estimate=False)

    # -- values ------------------------------------------------------------------------------
    def values(self, name: str) -> np.ndarray:
        """Channel ``name`` as an array of shape (1, width)."""
        width, lo, hi = CHANNELS[name]
        z = np.array(self.latents[name], np.float64)
        return (lo + (hi - lo) / (1 + np.exp(-z))).reshape(1, width)

    def set_values(self, name: str, values, kind: str | None = None) -> None:
        if kind not in (None, "constant"):
            raise ValueError(f"a constant material has no '{kind}' channels")
        self._set_all({**self._all(), name: values})

    def _all(self) -> dict[str, np.ndarray]:
        return {name: self.values(name)[0] for name in CHANNELS}

    def _set_all(self, values: dict) -> None:
        for name, (width, lo, hi) in CHANNELS.items():
            v = np.broadcast_to(np.asarray(values[name], np.float64).ravel(), width)
            z = mi.Float(np.array([_logit(x, lo, hi) for x in v], np.float32))
            if name in self.latents:
                mi.set_property(self.latents[name], z)  # in place: traversed parameters stay valid
            else:
                dr.make_opaque(z)
                self.latents[name] = z

    def restart_specular(self) -> None:
        self._set_all({**self._all(), "specular": START["specular"], "roughness": START["roughness"]})
        self.trainable = (*self.trainable, "specular")

    # -- optimisation interface -------------------------------------------------------------------
    def parameters(self) -> dict[str, mi.Float]:
        return dict(self.latents)

    def load_parameters(self, params: dict) -> None:
        for name, z in params.items():
            mi.set_property(self.latents[name], mi.Float(np.asarray(z, np.float32).ravel()))

    def display(self, mesh: Mesh) -> Mesh:
        v = self._all()
        out = Mesh(mesh.vertices, mesh.faces)
        out.vertex_colors = np.tile(v["albedo"].astype(np.float32), (mesh.n_vertices, 1))
        out.attributes = {"specular": np.full(mesh.n_vertices, v["specular"][0], np.float32),
                          "roughness": np.full(mesh.n_vertices, v["roughness"][0], np.float32)}
        return out

    # -- persistence ---------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        buf = io.BytesIO()
        np.savez(buf, kind=np.array(self.KIND), trainable=np.array(self.trainable, dtype=str), **self._all())
        fsio.write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> "ConstantMaterial":
        data = np.load(path)
        material = cls(data["albedo"], float(data["specular"][0]), float(data["roughness"][0]))
        material.trainable = tuple(str(x) for x in data["trainable"])
        return material

    def summary(self) -> dict:
        return {"model": "constant", "estimated": bool(self.trainable),
                **{k: np.round(x, 4).tolist() for k, x in self._all().items()}}
