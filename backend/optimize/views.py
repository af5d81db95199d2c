"""Target views: images premultiplied by their masks, resampled for coarse-to-fine levels
(``ViewSet``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..capture.images import area_resize, read_linear_rgb, read_mask
from ..capture.model import Camera, Capture, PointLight
from ..errors import require

PREMULTIPLIED_LEVEL = 1e-4  # brightest pixel outside the mask of a premultiplied image


@dataclass
class View:
    name: str
    camera: Camera
    target: np.ndarray  # (H, W, 3) linear, mask x image
    mask: np.ndarray | None  # (H, W) in [0, 1]
    lights: list[PointLight]


def scaled_camera(camera: Camera, w: int, h: int) -> Camera:
    """The camera for the frame resampled to w x h; square pixels stay square."""
    sx, sy = w / camera.width, h / camera.height
    s = 0.5 * (sx + sy) if abs(camera.fx - camera.fy) <= 1e-3 * camera.fx else None
    return Camera(w, h, camera.fx * (s or sx), camera.fy * (s or sy), camera.cx * sx, camera.cy * sy,
                  camera.camera_to_world.copy(), dict(camera.distortion))


def frame_size(camera: Camera, long_side: int) -> tuple[int, int]:
    f = min(1.0, long_side / max(camera.width, camera.height))
    return max(1, round(camera.width * f)), max(1, round(camera.height * f))


class ViewSet:
    """All frames of a capture, loaded once at most ``max_size`` pixels on the long side.

    The loss compares a render (black outside the object, since emitters are hidden) with
    mask x image, so it is the paper's masked MSE over the whole frame. Images that are already
    black outside their masks (synthetic renders) count as premultiplied and are used as they
    are, so anti-aliased edges are not multiplied by their coverage twice.
    """

    def __init__(self, capture: Capture, max_size: int):
        self.views: list[View] = []
        self.premultiplied = 0
        # per-frame gains (backend.lighting.exposure.Exposure), divided out of the targets by ``at``
        self.exposure = None
        for frame in capture.frames:
            image = capture.camera_response.radiance(read_linear_rgb(frame.image))
            mask = read_mask(frame.mask) if frame.mask else None
            for path, pixels in ((frame.image, image), (frame.mask, mask)):
                require(pixels is None or bool(np.all(np.isfinite(pixels))), path, "contains NaN or Inf pixels",
                        "re-export it with finite values (clip or repair the bad pixels)")
            if mask is not None:
                outside = image[mask <= 0.0]
                if outside.size and float(outside.max()) <= PREMULTIPLIED_LEVEL:
                    self.premultiplied += 1
                else:
                    image = image * mask[..., None]
            w, h = frame_size(frame.camera, max_size)
            self.views.append(View(frame.name, scaled_camera(frame.camera, w, h), area_resize(image, w, h),
                                   None if mask is None else area_resize(mask, w, h), frame.lights))

    def __len__(self) -> int:
        return len(self.views)

    def at(self, long_side: int, recorded: bool = False) -> list[View]:
        """The views resampled so their long side is at most ``long_side`` pixels, their targets
        divided by the frames' gains when ``exposure`` is set (``recorded``: as the frames are)."""
        out = []
        for i, v in enumerate(self.views):
            w, h = frame_size(v.camera, long_side)
            target = area_resize(v.target, w, h)
            if self.exposure is not None and not recorded:
                target = self.exposure.correct(i, target)
            out.append(View(v.name, scaled_camera(v.camera, w, h), target,
                            None if v.mask is None else area_resize(v.mask, w, h), v.lights))
        return out

    @property
    def max_size(self) -> int:
        return max(max(v.camera.width, v.camera.height) for v in self.views)


def validation_views(n_views: int, count: int) -> list[int]:
    """A fixed, evenly spread subset of view indices for convergence decisions."""
    count = max(1, min(count, n_views))
    return sorted({int(round(i * n_views / count)) % n_views for i in range(count)})
