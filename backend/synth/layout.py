"""Camera and light layouts for synthetic captures."""

from __future__ import annotations

import numpy as np

from ..capture.model import Camera, PointLight


def fibonacci_sphere(n: int, offset: float = 0.0) -> np.ndarray:
    """n nearly uniform unit directions; ``offset`` in [0, 1) shifts the spiral (for held-out views)."""
    i = np.arange(n) + 0.5 + offset
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    r = np.sqrt(np.clip(1 - z * z, 0, 1))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world (OpenGL camera axes) looking from ``eye`` at ``target``."""
    eye, target, up = map(lambda a: np.asarray(a, float), (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    if abs(np.dot(back, up)) > 0.999:
        up = np.array([0.0, 1.0, 0.0])
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(back, right), back, eye
    return m


def orbit_cameras(directions: np.ndarray, centre: np.ndarray, radius: float, resolution: int,
                  distance: float = 2.5, margin: float = 1.05) -> list[Camera]:
    """Cameras ``distance`` bounding-sphere radii away along ``directions``, framing the sphere."""
    half_fov = np.arcsin(1.0 / distance) * margin
    f = 0.5 * resolution / np.tan(half_fov)
    distance *= radius
    return [Camera(resolution, resolution, f, f, resolution / 2, resolution / 2,
                   look_at(centre + distance * d, centre)) for d in directions]


def paper_lights(camera: Camera, intensity: float) -> list[PointLight]:
    """The paper's layout: a light at the camera and one 1 unit along the camera's tangent (x axis)."""
    c = camera.centre
    tangent = camera.camera_to_world[:3, 0]
    power = np.full(3, float(intensity))
    return [PointLight(c.copy(), power), PointLight(c + tangent, power.copy())]


def flash_light(camera: Camera, intensity: float) -> list[PointLight]:
    """A flash: one light at the camera centre (a phone's flash, DTU-like captures)."""
    return [PointLight(camera.centre, np.full(3, float(intensity)))]
