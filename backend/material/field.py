"""The Dr.Jit side of the material: reparameterised values and the mesh-colors lookup.

Every stored value is a latent z (an unconstrained Dr.Jit leaf); the value the BSDF sees is
lo + (hi - lo) sigmoid(z), applied to each gathered sample before interpolating, so the
lookup is exactly linear in the sample *values* inside each sub-triangle and gradients
reach every latent without clamping."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np


def squash(z, lo: float, hi: float):
    """Latent -> value in (lo, hi) (Dr.Jit)."""
    return lo + (hi - lo) * dr.rcp(1.0 + dr.exp(-z))


def squash_np(z, lo: float, hi: float) -> np.ndarray:
    return lo + (hi - lo) / (1.0 + np.exp(-np.asarray(z, np.float64)))


def unsquash_np(v, lo: float, hi: float, eps: float = 1e-6) -> np.ndarray:
    """Value -> latent; values are kept eps inside (lo, hi)."""
    t = np.clip((np.asarray(v, np.float64) - lo) / (hi - lo), eps, 1 - eps)
    return np.log(t) - np.log1p(-t)


def corners(table: mi.UInt32, r: int, prim, uv, active):
    """[(shared sample index, weight)] x 3 interpolating mesh colors at (prim, uv = (b1, b2)).

    Mirrors MeshColorLayout.corners: sub-triangle (i, j) = floor(r (b1, b2)), upright
    corners (i, j), (i+1, j), (i, j+1) or inverted (i+1, j+1), (i, j+1), (i+1, j)."""
    if r == 0:
        return [(dr.gather(mi.UInt32, table, prim, active), mi.Float(1.0))]
    n_local = (r + 1) * (r + 2) // 2
    x = dr.clip(uv.x, 0.0, 1.0) * r
    y = dr.clip(uv.y, 0.0, 1.0) * r
    i = dr.clip(mi.Int32(dr.floor(x)), 0, r - 1)
    j = dr.clip(mi.Int32(dr.floor(y)), 0, r - 1 - i)
    fx, fy = x - mi.Float(i), y - mi.Float(j)
    upper = (fx + fy > 1.0) & (i + j < r - 1)

    def k(a, b):  # the paper's local index a (2r - a + 3) / 2 + b
        return mi.UInt32((a * (2 * r + 3 - a)) >> 1) + mi.UInt32(b)

    base = mi.UInt32(prim) * n_local
    local = [dr.select(upper, k(i + 1, j + 1), k(i, j)), k(i, j + 1), k(i + 1, j)]
    weights = [dr.select(upper, fx + fy - 1.0, 1.0 - fx - fy), dr.select(upper, 1.0 - fx, fy),
               dr.select(upper, 1.0 - fy, fx)]
    return [(dr.gather(mi.UInt32, table, base + kk, active), w) for kk, w in zip(local, weights)]


def corners_mixed(entries: mi.UInt32, offsets: mi.UInt32, resolutions: mi.Int32, prim, uv, active):
    """``corners`` with a per-face resolution (MeshColorLayout with an (F,) ``resolution``):
    r_f and the face's first entry are gathered per hit and the arithmetic is the same, so one
    kernel serves every resolution (every r_f >= 1)."""
    r = dr.gather(mi.Int32, resolutions, prim, active)
    base = dr.gather(mi.UInt32, offsets, prim, active)
    rf = mi.Float(r)
    x = dr.clip(uv.x, 0.0, 1.0) * rf
    y = dr.clip(uv.y, 0.0, 1.0) * rf
    i = dr.clip(mi.Int32(dr.floor(x)), 0, r - 1)
    j = dr.clip(mi.Int32(dr.floor(y)), 0, r - 1 - i)
    fx, fy = x - mi.Float(i), y - mi.Float(j)
    upper = (fx + fy > 1.0) & (i + j < r - 1)

    def k(a, b):
        return mi.UInt32((a * (2 * r + 3 - a)) >> 1) + mi.UInt32(b)

    local = [dr.select(upper, k(i + 1, j + 1), k(i, j)), k(i, j + 1), k(i + 1, j)]
    weights = [dr.select(upper, fx + fy - 1.0, 1.0 - fx - fy), dr.select(upper, 1.0 - fx, fy),
               dr.select(upper, 1.0 - fy, fx)]
    return [(dr.gather(mi.UInt32, entries, base + kk, active), w) for kk, w in zip(local, weights)]


class MeshColorsField:
    """Material field for SurfaceBSDF: reads the owning material's current Dr.Jit arrays."""

    def __init__(self, material):
        self.material = material

    def arrays(self) -> dict:
        """The latent arrays, exposed by SurfaceBSDF to mi.traverse as object.bsdf.<name>."""
        return self.material.parameters()

    def lookup(self, si, active):
        m = self.material
        prim = si.prim_index
        interp = None
        out = []
        for name, (width, lo, hi) in m.CHANNELS.items():
            ch = m.channels[name]
            kind = mi.Color3f if width == 3 else mi.Float
            if ch.kind == "constant":
                label = dr.gather(mi.UInt32, m.dr_labels, prim, active)
                out.append(squash(dr.gather(kind, ch.latent, label, active), lo, hi))
            else:
                if interp is None and m.layout.uniform:
                    interp = corners(m.dr_table, m.layout.resolution, prim, si.uv, active)
                elif interp is None:
                    interp = corners_mixed(m.dr_table, m.dr_offsets, m.dr_resolutions, prim, si.uv, active)
                out.append(sum(w * squash(dr.gather(kind, ch.latent, idx, active), lo, hi)
                               for idx, w in interp))
        return tuple(out)
