"""The constant material model, and the interface any material model offers the loop.

A material model provides:

- ``field``: what SurfaceBSDF reads (``lookup(si, active)`` and ``arrays()``);
- ``parameters()``: its latent Dr.Jit leaves by name; ``trainable``: the names the loop
  optimises (empty for a known material); ``load_parameters(dict)``: take new latents;
- ``attach(scene_params)``: scene parameters through which ``mi.render`` routes gradients;
- hooks ``on_subdivide(old_mesh, new_mesh)`` and ``on_remesh(new_mesh)`` for mesh changes;
- ``display(mesh) -> Mesh``: the snapshot mesh with per-vertex albedo, specular, roughness;
- ``save(path)`` / ``load(path)`` for --resume, and ``summary()`` for the report.

backend.material.model.MeshColorMaterial offers the same, so it can replace this one."""

from __future__ import annotations

import io
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import fsio
from ..errors import InputError
from ..geometry.mesh import Mesh

# name: (width, low, high); values are low + (high - low) sigmoid(latent)
CHANNELS = {"albedo": (3, 0.0, 1.0), "specular": (1, 0.0, 1.0), "roughness": (1, 0.0, 1.0)}
START = {"albedo": 0.5, "specular": 0.2, "roughness": 0.4}


def _logit(value: float, lo: float, hi: float) -> float:
    t = np.clip((value - lo) / (hi - lo), 1e-4, 1 - 1e-4)
    return float(np.log(t) - np.log1p(-t))


def _sigmoid(z, lo: float, hi: float):
    return lo + (hi - lo) * dr.rcp(1.0 + dr.exp(-z))


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


class ConstantField:
    """One albedo, specular and roughness for the whole surface, read through sigmoids of
    latent Dr.Jit arrays (so gradients reach the latents and values stay in range)."""

    def __init__(self, material: "ConstantMaterial"):
        self.material = material

    def arrays(self) -> dict:
        return self.material.parameters()

    def lookup(self, si, active):
        latents = self.material.latents
        out = []
        for name, (width, lo, hi) in CHANNELS.items():
            kind = mi.Color3f if width == 3 else mi.Float
            out.append(_sigmoid(dr.gather(kind, latents[name], 0), lo, hi))
        return tuple(out)


class ConstantMaterial:
    """A known (fixed) or estimated constant albedo (RGB), specular and roughness."""

    def __init__(self, albedo=START["albedo"], specular: float = START["specular"],
                 roughness: float = START["roughness"], estimate: bool = True):
        self.latents: dict[str, mi.Float] = {}
        self.set_values({"albedo": albedo, "specular": specular, "roughness": roughness})
        self.trainable = tuple(CHANNELS) if estimate else ()
        self.field = ConstantField(self)

    @classmethod
    def from_spec(cls, spec: str) -> "ConstantMaterial":
        """``auto`` (estimated, starting from neutral values) or ``known:R,G,B:SPEC:ROUGH``."""
        known = parse_spec(spec)
        return cls() if known is None else cls(*known, estimate=False)

    # -- values ------------------------------------------------------------------------------
    def values(self) -> dict[str, np.ndarray]:
        out = {}
        for name, (width, lo, hi) in CHANNELS.items():
            z = np.array(self.latents[name], np.float64)
            out[name] = lo + (hi - lo) / (1 + np.exp(-z))
        return out

    def set_values(self, values: dict) -> None:
        for name, (width, lo, hi) in CHANNELS.items():
            v = np.broadcast_to(np.asarray(values[name], np.float64).ravel(), width)
            z = mi.Float(np.array([_logit(x, lo, hi) for x in v], np.float32))
            if name in self.latents:
                mi.set_property(self.latents[name], z)  # in place: traversed parameters stay valid
            else:
                dr.make_opaque(z)
                self.latents[name] = z

    # -- optimisation interface -------------------------------------------------------------------
    def parameters(self) -> dict[str, mi.Float]:
        return dict(self.latents)

    def load_parameters(self, params: dict) -> None:
        for name, z in params.items():
            mi.set_property(self.latents[name], mi.Float(np.asarray(z, np.float32).ravel()))

    def attach(self, scene_params):
        return scene_params  # SurfaceBSDF already traverses field.arrays()

    def on_subdivide(self, old_mesh: Mesh, new_mesh: Mesh) -> None:
        pass  # constants do not depend on the mesh

    def on_remesh(self, new_mesh: Mesh, old_mesh: Mesh | None = None, reset: bool = True) -> None:
        pass

    def display(self, mesh: Mesh) -> Mesh:
        v = self.values()
        out = Mesh(mesh.vertices, mesh.faces)
        out.vertex_colors = np.tile(v["albedo"].astype(np.float32), (mesh.n_vertices, 1))
        out.attributes = {"specular": np.full(mesh.n_vertices, v["specular"][0], np.float32),
                          "roughness": np.full(mesh.n_vertices, v["roughness"][0], np.float32)}
        return out

    # -- persistence ---------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        buf = io.BytesIO()
        np.savez(buf, trainable=np.array(self.trainable, dtype=str), **self.values())
        fsio.write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> "ConstantMaterial":
        data = np.load(path)
        material = cls(data["albedo"], float(data["specular"][0]), float(data["roughness"][0]))
        material.trainable = tuple(str(x) for x in data["trainable"])
        return material

    def summary(self) -> dict:
        v = self.values()
        return {"model": "constant", "estimated": bool(self.trainable),
                **{k: np.round(x, 4).tolist() for k, x in v.items()}}
