"""Per-frame segmentation: GrabCut seeded by the projected object region, or an ONNX model.

Seeds of one frame (GrabCut's four labels): probable foreground inside the convex hull of the
object points' projections, widened by ``margin`` of its size; sure background outside that
hull grown by ``reach`` of its size, on a ``border``-pixel strip of the frame, and on the
observed features of points that are surely not the object's; sure foreground on the observed
features of the object's points. Everything else is probable background. The result keeps the
connected pieces that hold an object feature (or the largest)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

# cv2 is imported inside the functions: bpy must be imported before it in one process (tests, scripts)


@dataclass
class SeedOptions:
    margin: float = 0.08  # probable foreground: hull widened by this share of its size
    reach: float = 0.35  # sure background beyond the hull widened by this share of its size
    border: int = 3  # sure background strip along the frame's edges (pixels)
    feature_radius: int = 2  # disk of sure labels around an observed feature (pixels)
    iterations: int = 5  # GrabCut iterations
    smooth: float = 1.0  # Gaussian blur (pixels) of the frame GrabCut models colours on


def hull_polygon(uv: np.ndarray) -> np.ndarray | None:
    import cv2  # see the note at the top

    if len(uv) < 3:
        return None
    return cv2.convexHull(np.asarray(uv, np.float32)).reshape(-1, 2)


def _scaled(poly: np.ndarray, share: float) -> np.ndarray:
    """``poly`` grown about its centroid by ``share`` of its size (the longer bounding-box side)."""
    centre = poly.mean(0)
    size = float(np.max(poly.max(0) - poly.min(0)))
    d = poly - centre
    length = np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    return poly + d / length * share * size


def region_seeds(shape: tuple[int, int], hull: np.ndarray, fg_uv: np.ndarray, bg_uv: np.ndarray,
                 options: SeedOptions) -> np.ndarray:
    """GrabCut's label image (uint8) for a frame of ``shape`` (h, w): see the module docstring."""
    import cv2  # see the note at the top

    h, w = shape
    labels = np.full((h, w), cv2.GC_BGD, np.uint8)
    cv2.fillPoly(labels, [np.round(_scaled(hull, options.reach)).astype(np.int32)], cv2.GC_PR_BGD)
    cv2.fillPoly(labels, [np.round(_scaled(hull, options.margin)).astype(np.int32)], cv2.GC_PR_FGD)
    b = options.border
    labels[:b], labels[-b:], labels[:, :b], labels[:, -b:] = (cv2.GC_BGD,) * 4
    for uv, value in ((bg_uv, cv2.GC_BGD), (fg_uv, cv2.GC_FGD)):
        for x, y in np.round(np.asarray(uv).reshape(-1, 2) - 0.5).astype(int):
            if 0 <= x < w and 0 <= y < h:
                cv2.circle(labels, (int(x), int(y)), options.feature_radius, int(value), -1)
    return labels


def mask_seeds(shape: tuple[int, int], mask: np.ndarray, band: int, within: np.ndarray | None = None) -> np.ndarray:
    """GrabCut's labels from a mask (the visual hull's projection): sure foreground ``band``
    pixels inside its edge, sure background ``band`` pixels outside, probable between. With
    ``within`` (the frame's previous mask) foreground, sure or probable, is also inside it (eroded
    alike for the sure part): the hull bounds the object from outside only."""
    import cv2  # see the note at the top

    m = (np.asarray(mask) > 0.5).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band + 1, 2 * band + 1))
    inner, outer = cv2.erode(m, kernel), cv2.dilate(m, kernel)
    probable = m > 0
    if within is not None:
        w = (np.asarray(within) > 0.5).astype(np.uint8)
        probable &= w > 0
        inner = inner & cv2.erode(w, kernel)
    labels = np.full(shape, cv2.GC_BGD, np.uint8)
    labels[outer > 0] = cv2.GC_PR_BGD
    labels[probable] = cv2.GC_PR_FGD
    labels[inner > 0] = cv2.GC_FGD
    return labels


def grabcut(rgb: np.ndarray, labels: np.ndarray, iterations: int, keep_uv: np.ndarray | None = None,
            smooth: float = 0.0) -> np.ndarray:
    """The foreground (float32 0/1) GrabCut finds from ``labels`` on ``rgb`` blurred by a
    Gaussian of ``smooth`` pixels; the pieces holding a point of ``keep_uv`` (else the largest)."""
    import cv2  # see the note at the top

    labels = labels.copy()
    fg = (labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)
    if fg.all() or not fg.any():
        return fg.astype(np.float32)
    # GrabCut only on the box round the undecided pixels (with a band of sure background for its colour model)
    ys, xs = np.nonzero(labels != cv2.GC_BGD)
    pad = 16
    y0, y1 = max(0, ys.min() - pad), min(labels.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(labels.shape[1], xs.max() + pad + 1)
    crop = np.ascontiguousarray(labels[y0:y1, x0:x1])
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    bgr = np.ascontiguousarray(np.asarray(rgb, np.uint8)[y0:y1, x0:x1, ::-1])
    if smooth > 0:  # sensor (or render) noise widens both colour models until they overlap
        bgr = cv2.GaussianBlur(bgr, (0, 0), smooth)
    cv2.setRNGSeed(0)  # GrabCut's colour models start from OpenCV's global random state: same frame, same mask
    try:
        cv2.grabCut(bgr, crop, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error:  # one class has too few pixels to model: keep the seeds
        pass
    labels[y0:y1, x0:x1] = crop
    return keep_pieces(((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)), keep_uv)


def keep_pieces(mask: np.ndarray, keep_uv: np.ndarray | None = None) -> np.ndarray:
    """The connected pieces of ``mask`` that hold a point of ``keep_uv``, else the largest;
    holes smaller than 0.5 % of the object filled (float32 0/1)."""
    import cv2  # see the note at the top

    m = np.asarray(mask, np.uint8)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return m.astype(np.float32)
    keep = set()
    if keep_uv is not None and len(keep_uv):
        xy = np.floor(np.asarray(keep_uv)).astype(int)
        ok = (xy[:, 0] >= 0) & (xy[:, 1] >= 0) & (xy[:, 0] < m.shape[1]) & (xy[:, 1] < m.shape[0])
        hits = comp[xy[ok, 1], xy[ok, 0]]
        ids, counts = np.unique(hits[hits > 0], return_counts=True)
        keep = {int(i) for i, c in zip(ids, counts) if c >= max(2, 0.02 * counts.sum())}
    if not keep:
        keep = {int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) + 1}
    out = np.isin(comp, sorted(keep)).astype(np.uint8)
    holes = 1 - out
    nh, hcomp, hstats, _ = cv2.connectedComponentsWithStats(holes, connectivity=4)
    small = [i for i in range(1, nh) if hstats[i, cv2.CC_STAT_AREA] < 0.005 * out.sum()
             and hstats[i, cv2.CC_STAT_LEFT] > 0 and hstats[i, cv2.CC_STAT_TOP] > 0
             and hstats[i, cv2.CC_STAT_LEFT] + hstats[i, cv2.CC_STAT_WIDTH] < out.shape[1]
             and hstats[i, cv2.CC_STAT_TOP] + hstats[i, cv2.CC_STAT_HEIGHT] < out.shape[0]]
    if small:
        out[np.isin(hcomp, small)] = 1
    return out.astype(np.float32)


class OnnxSegmenter:
    """A salient-object network (ONNX, read by ``cv2.dnn``): input 1x3xSxS RGB in [0, 1]
    normalised by ImageNet's mean and deviation (U^2-Net's and most salient-object models'
    convention), output whose first channel is the foreground probability (or its logit) at
    any size; resized back to the frame and thresholded at 0.5."""

    MEAN = np.array([0.485, 0.456, 0.406])
    STD = np.array([0.229, 0.224, 0.225])

    def __init__(self, path: Path, size: int = 320):
        import cv2  # see the note at the top

        self.path, self.size = Path(path), int(size)
        try:
            self.net = cv2.dnn.readNetFromONNX(str(self.path))
        except cv2.error as err:
            first = str(err).strip().splitlines()[-1][:160] if str(err).strip() else "unreadable"
            raise InputError(self.path, f"not a model OpenCV can read ({first})",
                             "give an ONNX salient-object segmentation model, or leave --mask-model out "
                             "for the classical masks") from None

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        import cv2  # see the note at the top

        h, w = rgb.shape[:2]
        x = cv2.resize(np.asarray(rgb, np.float32) / 255.0, (self.size, self.size), interpolation=cv2.INTER_AREA)
        x = ((x - self.MEAN) / self.STD).astype(np.float32).transpose(2, 0, 1)[None]
        self.net.setInput(np.ascontiguousarray(x))
        try:
            y = np.asarray(self.net.forward(), np.float32)
        except cv2.error as err:
            raise InputError(self.path, f"the model failed on a {w}x{h} frame ({str(err).strip()[-120:]})",
                             "give a model with one 3-channel image input") from None
        y = y.reshape(-1, *y.shape[-2:])[0]
        if y.min() < 0 or y.max() > 1:
            y = 1 / (1 + np.exp(-y))
        return (cv2.resize(y, (w, h), interpolation=cv2.INTER_LINEAR) > 0.5).astype(np.float32)
