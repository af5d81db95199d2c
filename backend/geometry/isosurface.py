"""Level sets of a sampled scalar field by marching tetrahedra.

Each grid cube is split into six tetrahedra around its main diagonal (the Freudenthal
split, which neighbouring cubes share on their faces), and the field is linear inside each
tetrahedron. The level set of a piecewise-linear field at a regular value is a closed
2-manifold, so the result needs no repair: it is watertight and manifold whenever the
grid's outer layer lies outside the level set."""

from __future__ import annotations

import itertools

import numpy as np

from .mesh import Mesh
from .topology import clean

# Cube corner c = dx + 2 dy + 4 dz; tetrahedra follow the axis permutations from 0 to 7.
_TETS = np.array([[0, 1 << p[0], (1 << p[0]) | (1 << p[1]), 7] for p in itertools.permutations(range(3))])
_CORNERS = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], float)
_TET_SIGN = np.sign([np.linalg.det((_CORNERS[t[1:]] - _CORNERS[t[0]]).T) for t in _TETS]).astype(np.int64)


def _parity(order: np.ndarray) -> np.ndarray:
    """+1 for even, -1 for odd permutations (rows of ``order``)."""
    inversions = sum((order[:, i] > order[:, j]).astype(np.int64) for i in range(4) for j in range(i + 1, 4))
    return 1 - 2 * (inversions % 2)


def _regular(v: np.ndarray, iso: float, share: float = 0.01) -> np.ndarray:
    """Push samples within a hundredth of a typical crossing step away from ``iso`` (keeping
    their side), so no surface vertex lands on a grid point: no zero-area triangles."""
    a, b = v[:-1], v[1:]
    steps = np.abs(a - b)[(a > iso) != (b > iso)]
    delta = share * (float(np.median(steps)) if len(steps) else 1.0)
    near = np.abs(v - iso) < delta
    return np.where(near, np.where(v > iso, iso + delta, iso - delta), v)


def marching_tetrahedra(values: np.ndarray, iso: float, origin, spacing: float) -> Mesh:
    """The surface {x : field(x) = iso} wound so normals point toward lower values.

    ``values`` (nx, ny, nz) samples the field at ``origin + spacing * (i, j, k)``."""
    v = _regular(np.asarray(values, np.float64), iso)
    nx, ny, nz = v.shape
    inside = v > iso
    count = sum(inside[dx:nx - 1 + dx, dy:ny - 1 + dy, dz:nz - 1 + dz].astype(np.int8)
                for dx in (0, 1) for dy in (0, 1) for dz in (0, 1))
    cubes = np.argwhere((count > 0) & (count < 8))
    if len(cubes) == 0:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    strides = np.array([ny * nz, nz, 1])
    corner_offsets = np.array([(c & 1) * strides[0] + ((c >> 1) & 1) * strides[1] + ((c >> 2) & 1) * strides[2]
                               for c in range(8)])
    tets = (cubes @ strides)[:, None, None] + corner_offsets[_TETS][None]
    tets = tets.reshape(-1, 4)
    tet_sign = np.tile(_TET_SIGN, len(cubes))
    flat = v.ravel()
    ins = flat[tets] > iso
    n_in = ins.sum(1)

    # Triangles are wound combinatorially, which stays right for slivers: for a positively
    # oriented tetrahedron (p0, p1, p2, p3), the triangle cutting edges p0-p1, p0-p2, p0-p3
    # faces away from p0, and the quad cutting p0-p2, p0-p3, p1-p3, p1-p2 faces p2, p3.
    edges_a, edges_b, flips = [], [], []
    single = (n_in == 1) | (n_in == 3)
    if np.any(single):
        t, s = tets[single], ins[single]
        odd_is_inside = s.sum(1) == 1
        odd = np.where(odd_is_inside, np.argmax(s, 1), np.argmin(s, 1))
        order = np.argsort(np.arange(4)[None] != odd[:, None], axis=1, kind="stable")
        o = np.take_along_axis(t, order, 1)
        edges_a.append(np.repeat(o[:, :1], 3, 1))
        edges_b.append(o[:, 1:])
        flips.append(tet_sign[single] * _parity(order) * np.where(odd_is_inside, 1, -1) < 0)
    double = n_in == 2
    if np.any(double):
        t, s = tets[double], ins[double]
        order = np.argsort(~s, axis=1, kind="stable")  # inside, inside, outside, outside
        a, b, c, d = np.take_along_axis(t, order, 1).T
        edges_a += [np.stack([a, a, b], 1), np.stack([a, b, b], 1)]
        edges_b += [np.stack([c, d, d], 1), np.stack([c, d, c], 1)]
        flip = tet_sign[double] * _parity(order) < 0
        flips += [flip, flip]
    ea = np.concatenate(edges_a)
    eb = np.concatenate(edges_b)
    lo, hi = np.minimum(ea, eb), np.maximum(ea, eb)
    keys = lo.astype(np.int64) * flat.size + hi
    uniq, inverse = np.unique(keys.ravel(), return_inverse=True)
    p, q = uniq // flat.size, uniq % flat.size
    t = np.clip((iso - flat[p]) / (flat[q] - flat[p]), 0.0, 1.0)
    origin = np.asarray(origin, np.float64)

    def position(ids):
        return origin + spacing * np.stack(np.unravel_index(ids, v.shape), -1)

    verts = position(p) + t[:, None] * (position(q) - position(p))
    faces = inverse.reshape(-1, 3)
    flip = np.concatenate(flips)
    faces[flip] = faces[flip][:, ::-1]
    return clean(Mesh(verts, faces))
