"""Alignment of a captured environment map with the frames: its rotation about Z and its
strength (``capture-from-video``; the result is a :class:`MapAlignment`).

The coarse mesh (the masks' visual hull) is rendered with a constant diffuse albedo of 0.5
under the map (direct light, :mod:`.transport`) at a few views and a small size, and compared
with the linearised frames on pixels well inside the masks that are not clipped. Per colour
channel the gain that best scales the render onto the frame is solved in closed form at
every rotation, so the object's brightness and colour do not bias the rotation; beside it a
white glossy (GGX) image gets its own non-negative gain, so highlights are fitted rather than
read as diffuse shading turned towards the viewer. A coarse search over all rotations is
followed by a gradient refinement: a rotation by θ shifts the map's columns by θ·W/360
texels (periodic linear interpolation), whose derivative is exact, and the gains drop out of
the derivative because they are optimal (d loss/d gain = 0).

The object alone observes only the product exposure × white balance × strength × albedo.
Where the frames' background shows the surroundings, it fixes exposure × white balance ×
strength (:mod:`.response`); otherwise the camera response is normalised to exposure 1 and
white balance (1, 1, 1) and the strength is the mean of the three gains, i.e. the strength at
which the object's mean albedo is 0.5 (the material stages' start)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from PIL import Image

from ..capture.images import read_mask, read_rgba, srgb_to_linear
from ..capture.model import Camera, CameraResponse, Capture
from ..errors import require
from ..geometry.mesh import Mesh
from ..geometry.raycast import RayCaster, pixel_rays
from .response import MAX_ERROR as MAX_BACKGROUND_ERROR
from .response import BackgroundMatch, camera_response, match_background
from .transport import transport_matrix

CLIPPED = 254.0 / 255.0  # encoded 8-bit values at or above this are clipped
INTERIOR = 0.999  # share of a small pixel's source pixels that must be inside the mask and unclipped


@dataclass
class AlignConfig:
    """The alignment's sampling, search and refinement settings."""

    views: int = 8  # frames used, evenly spread
    size: int = 48  # long side of the small frames, pixels
    env_width: int = 64  # columns of the reduced map (rows: half)
    coarse_step_deg: float = 2.0
    # shading minima within this factor of the best are near-ties (a map with lights on
    # opposite sides): where the frames show the surroundings, the background decides
    tie_ratio: float = 1.25
    tie_window_deg: float = 10.0  # the background is searched this far around each tied minimum
    trim: float = 0.2  # share of pixels most brighter than the diffuse fit (highlights) dropped after the search
    gloss_alpha: float = 0.15  # GGX alpha of the glossy operator fitted beside the diffuse one (0: none)
    iterations: int = 40  # most refinement steps
    tolerance_deg: float = 0.01  # refinement stops when a step is smaller
    seed: int = 0


@dataclass
class MapAlignment:
    """Where a captured map sits and how bright it is, with the search that found it
    (``provenance()``: the capture's ``provenance.lighting``)."""

    rotation_z_deg: float
    strength: float
    gains: list[float]  # per channel: frame ≈ gain × diffuse render (albedo 0.5, strength 1) + glossy part
    loss: float  # relative squared residual at the estimate
    response: CameraResponse = field(default_factory=CameraResponse)
    scale_from: str = "mean albedo 0.5"  # or "background"
    background: BackgroundMatch | None = None
    coarse: list[tuple[float, float]] = field(default_factory=list)  # (degrees, loss) of the search
    refine: list[tuple[float, float]] = field(default_factory=list)  # (degrees, loss) of accepted steps
    views: list[str] = field(default_factory=list)
    pixels: int = 0
    seconds: float = 0.0
    ties: list[dict] = field(default_factory=list)  # near-tied shading minima and their background errors

    def provenance(self) -> dict:
        """The alignment as JSON (rounded curves), for capture.json's provenance."""
        return {"aligned": True, "rotation_z_deg": self.rotation_z_deg, "strength": self.strength,
                "gains": self.gains, "loss": self.loss, "views": self.views, "pixels": self.pixels,
                "seconds": round(self.seconds, 2),
                "coarse_curve": [[round(a, 3), float(f"{b:.6g}")] for a, b in self.coarse],
                "refine_curve": [[round(a, 4), float(f"{b:.6g}")] for a, b in self.refine],
                "scale_from": self.scale_from,
                "background": self.background.provenance() if self.background else None,
                "ties": self.ties}


def _box(array: np.ndarray, width: int, height: int) -> np.ndarray:
    """An image (H, W) or (H, W, C) box-filtered to ``width`` x ``height``."""
    if array.shape[:2] == (height, width):
        return array.astype(np.float32)
    chans = array[..., None] if array.ndim == 2 else array
    out = np.stack([np.asarray(Image.fromarray(np.ascontiguousarray(chans[..., c], np.float32), "F")
                               .resize((width, height), Image.BOX)) for c in range(chans.shape[-1])], -1)
    return out[..., 0] if array.ndim == 2 else out


def reduce_environment(pixels: np.ndarray, width: int) -> np.ndarray:
    """The map box-filtered to ``width`` x ``width / 2`` (kept when it is smaller)."""
    if pixels.shape[1] <= width:
        return np.asarray(pixels[..., :3], np.float32)
    return _box(np.asarray(pixels[..., :3], np.float32), width, width // 2)


def frame_samples(capture: Capture, config: AlignConfig
                  ) -> list[tuple[str, Camera, np.ndarray, np.ndarray, np.ndarray]]:
    """(name, small camera, linear frame, object pixels, background pixels) of evenly spread
    frames; the pixels are wholly inside (outside) the mask and unclipped."""
    frames = capture.frames
    picks = sorted({int(i) for i in np.linspace(0, len(frames), config.views, endpoint=False)})
    out = []
    for i in picks:
        frame = frames[i]
        pixels, linear = read_rgba(frame.image)
        rgb = pixels[..., :3]
        mask = read_mask(frame.mask) if frame.mask is not None else np.ones(rgb.shape[:2], np.float32)
        unclipped = np.ones(rgb.shape[:2], bool) if linear else rgb.max(-1) < CLIPPED
        rgb = rgb if linear else srgb_to_linear(rgb)
        cam = frame.camera
        f = min(1.0, config.size / max(cam.width, cam.height))
        small = cam.scaled(f)
        share = [_box((m & unclipped).astype(np.float32), small.width, small.height) >= INTERIOR
                 for m in (mask > 0.5, mask <= 0.0)]
        out.append((frame.name, small, _box(rgb, small.width, small.height), *share))
    return out


def shift_columns(env: np.ndarray, degrees: float) -> tuple[np.ndarray, np.ndarray]:
    """The map as seen at rotation ``degrees`` and its derivative per degree: column j takes
    the (periodic, linearly interpolated) value at j − s, s = degrees·W/360."""
    w = env.shape[1]
    s = degrees * w / 360.0
    k = int(np.floor(s))
    f = s - k
    a = np.roll(env, k, axis=1)  # a[:, j] = env[:, j - k]
    b = np.roll(env, k + 1, axis=1)  # env[:, j - k - 1]
    return (1 - f) * a + f * b, (b - a) * (w / 360.0)


class RotationLoss:
    """Relative squared residual between frames and renders as a function of the rotation,
    with its exact derivative. Renders are the operators' images (diffuse first, then an
    optional glossy one) combined per channel with the least-squares coefficients (the
    glossy one kept >= 0)."""

    def __init__(self, matrices: list[np.ndarray], env: np.ndarray, targets: np.ndarray):
        self.matrices = matrices  # each (N, texels)
        self.env = env  # (H, W, 3) reduced map
        self.targets = targets.astype(np.float64)  # (N, 3)
        self.norm = float((self.targets ** 2).sum())

    def subset(self, keep: np.ndarray) -> "RotationLoss":
        """The loss on the pixels ``keep`` selects."""
        return RotationLoss([m[keep] for m in self.matrices], self.env, self.targets[keep])

    def _fit(self, env: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(coefficients (B, 3), fitted images (N, 3)) for the shifted map."""
        flat = env.reshape(-1, 3).astype(np.float32)
        renders = np.stack([(m @ flat).astype(np.float64) for m in self.matrices])  # (B, N, 3)
        coeffs = np.zeros((len(renders), 3))
        for c in range(3):
            a, y = renders[:, :, c].T, self.targets[:, c]
            x = np.linalg.lstsq(a, y, rcond=None)[0] if len(renders) > 1 else np.zeros(1)
            if len(renders) == 1 or np.any(x[1:] < 0):
                x = np.zeros(len(renders))
                x[0] = (a[:, 0] @ y) / max(a[:, 0] @ a[:, 0], 1e-30)
            coeffs[:, c] = x
        return coeffs, np.einsum("bc,bnc->nc", coeffs, renders)

    def brighter(self, degrees: float) -> np.ndarray:
        """How much brighter each pixel is than the fit, relative to the fit (N,)."""
        fit = self._fit(shift_columns(self.env, degrees)[0])[1].sum(1)
        return (self.targets.sum(1) - fit) / np.maximum(fit, 1e-6 * max(fit.max(), 1e-30))

    def __call__(self, degrees: float, gradient: bool = True) -> tuple[float, float, np.ndarray]:
        """(loss, d loss / d degree, per-channel gains of the diffuse image)."""
        env, d_env = shift_columns(self.env, degrees)
        coeffs, fit = self._fit(env)
        residual = self.targets - fit
        loss = float((residual ** 2).sum()) / self.norm
        if not gradient:
            return loss, 0.0, coeffs[0]
        r = residual.astype(np.float32)
        back = sum(coeffs[b] * (m.T @ r) for b, m in enumerate(self.matrices))  # (texels, 3)
        grad = -2.0 * float((back * d_env.reshape(-1, 3)).sum()) / self.norm
        return loss, grad, coeffs[0]


def refine(loss: RotationLoss, start: float, step: float, config: AlignConfig,
           progress=lambda i, deg, value: None) -> tuple[float, list[tuple[float, float]]]:
    """Gradient descent on the rotation: secant (Newton on the derivative) steps where the
    loss curves upwards, else steps along the negative gradient, each at most ``step``
    degrees and halved until the loss decreases."""
    theta = start
    value, grad, _ = loss(theta)
    curve = [(theta, value)]
    prev = None
    for i in range(config.iterations):
        if grad == 0:
            break
        move = -np.sign(grad) * step
        if prev is not None and theta != prev[0]:
            curvature = (grad - prev[1]) / (theta - prev[0])
            if curvature > 0:
                move = float(np.clip(-grad / curvature, -step, step))
        while abs(move) >= config.tolerance_deg:
            trial_value, trial_grad, _ = loss(theta + move)
            if trial_value < value:
                break
            move *= 0.5
        if abs(move) < config.tolerance_deg:
            break
        prev = (theta, grad)
        theta, value, grad = theta + move, trial_value, trial_grad
        curve.append((theta, value))
        progress(i + 1, theta, value)
    return theta, curve


def align_lighting(capture: Capture, mesh: Mesh, env_pixels: np.ndarray, config: AlignConfig | None = None,
                   rotation_z_deg: float | None = None, emit=lambda kind, **fields: None) -> MapAlignment:
    """The map's rotation about Z (unless ``rotation_z_deg`` gives it) and strength, from the frames.

    ``mesh`` is the coarse object (the visual hull); ``env_pixels`` the full map (H, W, 3);
    ``emit`` gets ``progress`` events. Needs a Mitsuba variant chosen (``backend.variant.choose()``)."""
    config = config or AlignConfig()
    start = time.time()
    caster = RayCaster(mesh)
    samples = frame_samples(capture, config)
    points, normals, views, targets = [], [], [], []
    for name, camera, rgb, usable, _ in samples:
        ys, xs = np.nonzero(usable)
        origins, dirs = pixel_rays(camera, np.c_[xs, ys])
        hits = caster.intersect(origins, dirs)
        hit = hits.hit
        points.append(hits.points[hit])
        normals.append(hits.shading_towards(dirs)[hit])
        views.append(-dirs[hit])
        targets.append(rgb[ys[hit], xs[hit]])
    points, normals, views, targets = (np.concatenate(a) for a in (points, normals, views, targets))
    require(len(points) >= 50 and float(np.abs(targets).sum()) > 0, capture.root,
            f"only {len(points)} usable object pixels (inside the masks, unclipped, on the hull) to align the "
            "lighting with", "check the masks, or pass --no-align-lighting")
    env = reduce_environment(env_pixels, config.env_width)
    emit("progress", stage="lighting:transport", pixels=len(points), texels=env.shape[0] * env.shape[1])
    matrices = transport_matrix(caster, points, normals, env.shape[1], env.shape[0], config.seed, views,
                                config.gloss_alpha)
    loss = RotationLoss(list(matrices) if config.gloss_alpha > 0 else [matrices], env, targets)

    coarse = []
    if rotation_z_deg is None:
        grid = np.arange(0.0, 360.0, config.coarse_step_deg)
        for k, deg in enumerate(grid):
            coarse.append((float(deg), loss(float(deg), gradient=False)[0]))
            if (k + 1) % 30 == 0 or k + 1 == len(grid):
                emit("progress", stage="lighting:search", iteration=k + 1, iterations=len(grid),
                     fraction=(k + 1) / len(grid))
        best = min(coarse, key=lambda c: c[1])[0]
        decided, ties = break_ties(coarse, samples, env_pixels, config)
    if rotation_z_deg is None and decided is not None:  # the surroundings fix it more sharply than shading
        theta, curve = decided, [(decided, loss(decided, gradient=False)[0])]
    elif rotation_z_deg is None:
        if config.trim > 0:  # drop highlights, then search again near the best rotation
            excess = loss.brighter(best)
            loss = loss.subset(excess <= np.quantile(excess, 1.0 - config.trim))
            near = best + np.arange(-10, 11) * config.coarse_step_deg
            best = float(min(near, key=lambda deg: loss(float(deg), gradient=False)[0]))

        def progress(i, deg, value):
            emit("progress", stage="lighting:refine", iteration=i, iterations=config.iterations,
                 rotation_z_deg=round(deg % 360.0, 3), loss=value)

        theta, curve = refine(loss, best, config.coarse_step_deg, config, progress)
    else:
        theta, ties = float(rotation_z_deg), []
        curve = [(theta, loss(theta, gradient=False)[0])]
    value, _, gains = loss(theta, gradient=False)
    background = match_background([(s[1], s[2], s[4]) for s in samples], reduce_environment(env_pixels, 256), theta)
    response, strength, scale_from = camera_response(gains, background)
    return MapAlignment(rotation_z_deg=float(theta % 360.0), strength=strength,
                            gains=[float(g) for g in gains], loss=value, response=response, scale_from=scale_from,
                            background=background, coarse=coarse, refine=[(d % 360.0, v) for d, v in curve],
                            views=[s[0] for s in samples], pixels=len(points), seconds=time.time() - start,
                            ties=ties)


def break_ties(coarse: list[tuple[float, float]], samples, env_pixels: np.ndarray,
               config: AlignConfig) -> tuple[float | None, list[dict]]:
    """When the coarse shading curve has several local minima within ``tie_ratio`` of the
    lowest and the frames' background (the surroundings the map shows) fits near one of them
    (relative squared residual below the response's bar), the rotation the background fits
    best there, to 0.25 degrees; else None (the shading decides). Also returns the tied
    minima with their background errors (1 = no fit)."""
    degrees = np.array([c[0] for c in coarse])
    values = np.array([c[1] for c in coarse])
    lowest = float(values.min())
    minima = [i for i in range(len(values))
              if values[i] <= values[i - 1] and values[i] <= values[(i + 1) % len(values)]
              and values[i] <= config.tie_ratio * lowest]
    if len(minima) < 2:
        return None, []
    env = reduce_environment(env_pixels, 256)
    pairs = [(s[1], s[2], s[4]) for s in samples]
    ties = []
    for i in minima:
        window = degrees[i] + np.arange(-config.tie_window_deg, config.tie_window_deg + 1e-9, config.coarse_step_deg)
        fits = [(match_background(pairs, env, float(d)), float(d)) for d in window]
        fits = [(m.error, d) for m, d in fits if m is not None]
        if not fits:  # too little background to decide
            return None, []
        error, at = min(fits)
        ties.append({"rotation_z_deg": float(degrees[i]), "loss": float(values[i]), "background_error": error,
                     "background_best_deg": at})
    chosen = min(ties, key=lambda t: t["background_error"])
    if chosen["background_error"] > MAX_BACKGROUND_ERROR:  # the background fits none: shading decides
        return None, ties
    chosen["chosen"] = True
    fine = chosen["background_best_deg"] + np.arange(-config.coarse_step_deg, config.coarse_step_deg + 1e-9, 0.25)
    error, at = min((match_background(pairs, env, float(d)).error, float(d)) for d in fine)
    chosen["background_error"], chosen["background_best_deg"] = error, at
    return at, ties
