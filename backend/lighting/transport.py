"""Direct light on a constant diffuse surface as a linear map of the environment's pixels.

A pixel whose camera ray first hits the surface at x (normal n) receives, from an
equirectangular map E with texels t of solid angle Ω_t,

    L = (albedo / π) Σ_t E_t Ω_t V(x, ω_t) max(0, n·ω_t)

(one direction ω_t per texel and pixel, jittered inside the texel; V = 1 when the ray
from x towards ω_t escapes the mesh). A second, glossy operator replaces albedo/π · n·ω by
a white GGX lobe D G / (4 n·v) (v towards the camera), for highlights to be fitted
rather than mistaken for diffuse shading. So a render is ``matrix @ E`` with a fixed matrix:
a change of E (a rotation is a shift of its columns) is exact and costs one product,
and the result is a smooth function of E with no Monte Carlo noise between evaluations.
Directions follow the capture format's environment lookup at rotation 0: texel column u,
row v look along (sin θ cos φ, sin θ sin φ, cos θ), φ = π(1 − 2u), θ = πv."""

from __future__ import annotations

import numpy as np

from ..geometry.raycast import RayCaster

ALBEDO = 0.5
ROWS_PER_CHUNK = 512  # pixels whose shadow rays are traced together


def texel_solid_angles(width: int, height: int) -> np.ndarray:
    """Solid angle of each texel row (all texels of a row are equal), (height,)."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (2 * np.pi / width) * (edges[:-1] - edges[1:])


def directions(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """World directions of equirectangular coordinates (u, v) in [0, 1] at rotation 0."""
    phi, theta = np.pi * (1.0 - 2.0 * u), np.pi * v
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], -1)


def _ggx(n: np.ndarray, v: np.ndarray, w: np.ndarray, alpha: float) -> np.ndarray:
    """D G / (4 n·v) of a GGX lobe (Smith G), for normals, view and light directions (M, 3)."""
    h = v + w
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    a2 = alpha * alpha
    cos_h, cos_v, cos_w = (n * h).sum(1), np.maximum((n * v).sum(1), 1e-4), (n * w).sum(1)
    d = a2 / (np.pi * (cos_h ** 2 * (a2 - 1.0) + 1.0) ** 2)

    def g1(c):
        return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))

    return d * g1(cos_v) * g1(cos_w) / (4.0 * cos_v)


def transport_matrix(caster: RayCaster, points: np.ndarray, normals: np.ndarray, width: int, height: int,
                     seed: int = 0, views: np.ndarray | None = None, alpha: float = 0.0) -> np.ndarray:
    """(N, height * width) float32: the diffuse (albedo ALBEDO) direct-light operator, or with
    ``views`` (unit vectors towards the camera, (N, 3)) and ``alpha`` > 0 a pair (diffuse,
    glossy) built from the same shadow rays."""
    rng = np.random.default_rng(seed)
    n_tex = width * height
    rows, cols = np.divmod(np.arange(n_tex), width)
    omega = texel_solid_angles(width, height)[rows]
    glossy = views is not None and alpha > 0
    out = np.zeros((len(points), n_tex), np.float32)
    gloss = np.zeros((len(points), n_tex), np.float32) if glossy else None
    for s in range(0, len(points), ROWS_PER_CHUNK):
        p, n = points[s:s + ROWS_PER_CHUNK], normals[s:s + ROWS_PER_CHUNK]
        jitter = rng.random((len(p), n_tex, 2))
        d = directions((cols + jitter[..., 0]) / width, (rows + jitter[..., 1]) / height)
        cos = np.einsum("nk,ntk->nt", n, d)
        i, t = np.nonzero(cos > 0)
        free = caster.escapes(p[i] + caster.epsilon * n[i], d[i, t])
        i, t = i[free], t[free]
        out[s + i, t] = cos[i, t] * omega[t] * (ALBEDO / np.pi)
        if glossy:
            gloss[s + i, t] = _ggx(n[i], views[s + i], d[i, t], alpha) * cos[i, t] * omega[t]
    return (out, gloss) if glossy else out
