"""The capture model. World frame = Blender's (Z up, metres).

Cameras use Blender/OpenGL camera axes (x right, y up, looking along -z) in
``camera_to_world``. Intrinsics are in pixels with the image's top-left *corner* at
(0, 0), so the centre of the top-left pixel is (0.5, 0.5) (COLMAP's convention)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# OpenCV camera axes (x right, y down, z forward) <-> Blender/OpenGL camera axes.
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class Camera:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    camera_to_world: np.ndarray  # 4x4, OpenGL camera axes
    distortion: dict[str, float] = field(default_factory=dict)  # OpenCV k1 k2 p1 p2 [k3]

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def world_to_camera(self) -> np.ndarray:
        return np.linalg.inv(self.camera_to_world)

    @property
    def centre(self) -> np.ndarray:
        return self.camera_to_world[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        return -self.camera_to_world[:3, 2] / np.linalg.norm(self.camera_to_world[:3, 2])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pinhole projection of world points to pixel coordinates; returns (uv, depth).

        Depth is positive in front of the camera. Distortion is ignored (undistort first)."""
        p = np.c_[points, np.ones(len(points))] @ (CV_TO_GL @ self.world_to_camera).T
        z = p[:, 2]
        safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
        uv = np.stack([self.fx * p[:, 0] / safe + self.cx, self.fy * p[:, 1] / safe + self.cy], -1)
        return uv, z

    def scaled(self, factor: float) -> "Camera":
        """The same camera for an image resized by ``factor``."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return Camera(w, h, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy,
                      self.camera_to_world.copy(), dict(self.distortion))

    def to_json(self) -> dict:
        out = {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy,
               "cx": self.cx, "cy": self.cy, "camera_to_world": self.camera_to_world.tolist()}
        if self.distortion:
            out["distortion"] = dict(self.distortion)
        return out


@dataclass
class PointLight:
    position: np.ndarray  # world, metres
    intensity: np.ndarray  # RGB radiant intensity, W/sr

    def to_json(self) -> dict:
        return {"type": "point", "position": list(map(float, self.position)),
                "intensity_w_per_sr": list(map(float, self.intensity))}


@dataclass
class Environment:
    """Equirectangular HDR map placed as Blender's World Environment Texture places it.

    Direction d (world, Z up) looks up the image at u = 0.5 - atan2(d'.y, d'.x) / 2pi,
    v = acos(d'.z) / pi (v = 0 is the top row), where d' = Rz(rotation_z_deg) d, which is
    what a Mapping node (Point, rotation Z) between Generated coordinates and the texture
    does. Radiance is the pixel value times ``strength``.

    ``frame`` "camera": the map is fixed to each view's camera instead of the world (lamps on
    the camera rig; ``--lighting rig``). d is then the direction in the camera's rig frame:
    x toward the camera (its GL +z), y its right (+x), z its up (+y), so the map's centre
    column at the horizon is the light coming from the camera."""

    path: Path
    strength: float = 1.0
    rotation_z_deg: float = 0.0
    provenance: str = "given"  # or "estimated" (lighting alignment, backend.lighting)
    # the map's pixels held in memory (H, W, 3), read instead of ``path`` (a map being fitted:
    # backend.lighting.estimated_map; ``path`` is where it is written)
    pixels: np.ndarray | None = field(default=None, repr=False, compare=False)
    frame: str = "world"  # or "camera": fixed to each view's camera (see above); or "world+camera"
    # "world+camera" (``--lighting world+rig``, backend.lighting.summed_map): ``path``/``pixels`` is
    # the world-fixed map and this second map, fixed to the camera, is added to it in every view
    rig_path: Path | None = None
    rig_pixels: np.ndarray | None = field(default=None, repr=False, compare=False)

    def scaled(self, factor: float) -> "Environment":
        """The same map ``factor`` times as bright (a fitted light factor applied)."""
        return Environment(self.path, self.strength * factor, self.rotation_z_deg, self.provenance, self.pixels,
                           self.frame, self.rig_path, self.rig_pixels)

    @staticmethod
    def rig_axes(camera_to_world: np.ndarray) -> np.ndarray:
        """(3, 3) whose columns are the rig frame's x, y, z in world coordinates: the camera's
        GL +z (toward the camera), +x (right) and +y (up)."""
        r = np.asarray(camera_to_world, np.float64)[:3, :3]
        return np.stack([r[:, 2], r[:, 0], r[:, 1]], 1)

    def to_json(self, root: Path) -> dict:
        out = {"path": _rel(self.path, root), "strength": self.strength, "rotation_z_deg": self.rotation_z_deg}
        if self.provenance != "given":
            out["provenance"] = self.provenance
        return out


@dataclass
class CameraResponse:
    """How the camera turned scene radiance into the frames' pixel values.

    A frame pixel is curve(exposure x white_balance x radiance): ``curve`` "srgb" is the
    sRGB transfer curve of 8- and 16-bit frames (EXR/HDR frames are linear and skip it);
    one exposure and three white-balance gains per video. ``radiance`` inverts the gains
    for frames already linearised on load."""

    exposure: float = 1.0
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    curve: str = "srgb"
    provenance: str = "default"  # "given", "estimated" or "default" (identity)

    @property
    def gains(self) -> np.ndarray:
        return self.exposure * np.asarray(self.white_balance, np.float32)

    def radiance(self, linear: np.ndarray) -> np.ndarray:
        """Scene radiance from a linearised frame (H, W, 3)."""
        if self.exposure == 1.0 and tuple(self.white_balance) == (1.0, 1.0, 1.0):
            return linear
        return (np.asarray(linear, np.float32) / self.gains).astype(np.float32)

    def to_json(self) -> dict:
        return {"curve": self.curve, "exposure": self.exposure,
                "white_balance": [float(x) for x in self.white_balance], "provenance": self.provenance}


@dataclass
class Frame:
    name: str
    image: Path
    camera: Camera
    mask: Path | None = None
    material_mask: Path | None = None  # integer labels per pixel (0 = unassigned)
    lights: list[PointLight] = field(default_factory=list)

    def to_json(self, root: Path) -> dict:
        out = {"name": self.name, "image": _rel(self.image, root), "camera": self.camera.to_json()}
        if self.mask:
            out["mask"] = _rel(self.mask, root)
        if self.material_mask:
            out["material_mask"] = _rel(self.material_mask, root)
        if self.lights:
            out["lights"] = [light.to_json() for light in self.lights]
        return out


@dataclass
class Capture:
    root: Path
    frames: list[Frame]
    environment: Environment | None = None
    points: Path | None = None  # sparse SfM points (PLY), for initialisation
    provenance: dict = field(default_factory=dict)
    ground_truth: dict = field(default_factory=dict)  # paths relative to root, e.g. {"mesh": ...}
    camera_response: CameraResponse = field(default_factory=CameraResponse)

    @property
    def has_masks(self) -> bool:
        return all(f.mask is not None for f in self.frames)

    @property
    def has_point_lights(self) -> bool:
        return any(f.lights for f in self.frames)

    def path(self, rel: str | None) -> Path | None:
        return None if rel is None else (self.root / rel)

    def bounds_hint(self) -> tuple[np.ndarray, float]:
        """A centre and radius that the cameras look at (least-squares ray convergence)."""
        A = np.zeros((3, 3))
        b = np.zeros(3)
        for f in self.frames:
            d = f.camera.forward
            P = np.eye(3) - np.outer(d, d)
            A += P
            b += P @ f.camera.centre
        centre = np.linalg.lstsq(A, b, rcond=None)[0]
        dist = np.median([np.linalg.norm(f.camera.centre - centre) for f in self.frames])
        half_fov = min(np.arctan(0.5 * f.camera.height / f.camera.fy) for f in self.frames)
        return centre, float(dist * np.sin(half_fov))


def _rel(path: Path, root: Path) -> str:
    path = Path(path)
    try:
        return path.resolve().relative_to(Path(root).resolve()).as_posix()
    except ValueError:
        return str(path.resolve())
