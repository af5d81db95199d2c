"""The one pixel-ray convention (rays through pixel centres) and the one first-hit caster."""

from __future__ import annotations

import numpy as np

from backend import variant

variant.choose()

from backend.geometry.primitives import icosphere  # noqa: E402
from backend.geometry.raycast import RayCaster, pixel_rays  # noqa: E402
from backend.synth.layout import fibonacci_sphere, orbit_cameras  # noqa: E402


def test_pixel_rays_pass_through_pixel_centres():
    cam = orbit_cameras(fibonacci_sphere(3), np.zeros(3), 3.0, 12)[1]
    origins, dirs = pixel_rays(cam)
    assert origins.shape == dirs.shape == (cam.width * cam.height, 3)
    assert np.allclose(np.linalg.norm(dirs, axis=1), 1.0)
    uv, depth = cam.project(origins + 2.0 * dirs)
    ys, xs = np.mgrid[0:cam.height, 0:cam.width]
    assert np.all(depth > 0)
    assert np.allclose(uv, np.c_[xs.ravel(), ys.ravel()] + 0.5, atol=1e-9)  # rows top to bottom
    some = np.array([[0, 0], [5, 7], [cam.width - 1, cam.height - 1]])
    o, d = pixel_rays(cam, some)
    assert np.allclose(d, dirs[some[:, 1] * cam.width + some[:, 0]])


def test_first_hits_on_a_sphere():
    sphere = icosphere(4, 0.5)
    cam = orbit_cameras(fibonacci_sphere(2), np.zeros(3), 0.5, 24)[0]
    origins, dirs = pixel_rays(cam)
    hits = RayCaster(sphere).intersect(origins, dirs)
    assert 50 < hits.hit.sum() < len(dirs)
    p = hits.points[hits.hit]
    assert np.allclose(np.linalg.norm(p, axis=1), 0.5, atol=0.01)
    assert np.all(np.einsum("ij,ij->i", hits.normals[hits.hit], p) > 0)  # outward by winding
    assert np.allclose(hits.points[hits.hit], origins[hits.hit] + hits.distance[hits.hit, None] * dirs[hits.hit],
                       atol=1e-4)
    facing = hits.shading_towards(dirs)[hits.hit]
    assert np.all(np.einsum("ij,ij->i", facing, dirs[hits.hit]) < 0)
    assert not RayCaster(sphere).escapes(origins[hits.hit], dirs[hits.hit]).any()
