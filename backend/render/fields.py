"""Material fields: where the BSDF reads albedo, specular and roughness at a surface point."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


class ConstantField:
    """One albedo (RGB), specular and roughness for the whole surface (Dr.Jit arrays of size 1).

    The arrays are opaque (evaluated), never literals: a literal would be baked into every
    kernel, forcing a recompile for each new value and letting LLVM constant-fold it."""

    def __init__(self, albedo, specular: float, roughness: float):
        self.albedo = mi.Color3f(*(float(a) for a in np.broadcast_to(np.asarray(albedo, float), 3)))
        self.specular = mi.Float(float(specular))
        self.roughness = mi.Float(float(roughness))
        dr.make_opaque(self.albedo, self.specular, self.roughness)

    def lookup(self, si, active):
        return self.albedo, dr.gather(mi.Float, self.specular, 0), dr.gather(mi.Float, self.roughness, 0)

    def arrays(self) -> dict:
        return {"albedo": self.albedo, "specular": self.specular, "roughness": self.roughness}


class VertexField:
    """Per-vertex values interpolated with the hit point's barycentrics (si.uv on UV-less meshes)."""

    def __init__(self, faces: np.ndarray, albedo: np.ndarray, specular: np.ndarray, roughness: np.ndarray):
        self.faces = mi.UInt32(np.asarray(faces, np.uint32).ravel())
        self.albedo = mi.Float(np.asarray(albedo, np.float32).ravel())
        self.specular = mi.Float(np.asarray(specular, np.float32).ravel())
        self.roughness = mi.Float(np.asarray(roughness, np.float32).ravel())

    def lookup(self, si, active):
        idx = [dr.gather(mi.UInt32, self.faces, si.prim_index * 3 + k, active) for k in range(3)]
        b1, b2 = si.uv.x, si.uv.y
        w = [1.0 - b1 - b2, b1, b2]
        albedo = sum(w[k] * dr.gather(mi.Color3f, self.albedo, idx[k], active) for k in range(3))
        spec = sum(w[k] * dr.gather(mi.Float, self.specular, idx[k], active) for k in range(3))
        rough = sum(w[k] * dr.gather(mi.Float, self.roughness, idx[k], active) for k in range(3))
        return albedo, spec, rough

    def arrays(self) -> dict:
        return {"albedo": self.albedo, "specular": self.specular, "roughness": self.roughness}
