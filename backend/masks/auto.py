"""The automatic masks of a set of frames with SfM cameras (the package docstring says how and why)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError, require
from .cameras import View, views_of
from .consistency import Votes, iou, project_hull
from .ground import ground_difference
from .region import NO_OBJECT_FIX, Region, object_region
from .outline import OutlineOptions, refine_outline
from .segment import OnnxSegmenter, SeedOptions, grabcut, hull_polygon, mask_seeds, region_seeds


@dataclass
class MaskOptions:
    object_box: tuple[float, ...] | None = None  # orbit frame (x0, y0, z0, x1, y1, z1); None: near the focus
    model: Path | None = None  # an ONNX segmentation model instead of GrabCut
    model_size: int = 320  # the model's square input side
    seeds: SeedOptions = field(default_factory=SeedOptions)
    min_iou: float = 0.8  # a mask agreeing less with the others' visual hull drops its frame
    grid: int = 80  # voxels along the hull box's longer side
    tolerance_share: float = 0.1  # views that may disagree with a kept voxel (share, at least one)
    edge: float = 0.01  # a region (0.5..99.5 percentiles of its points) this near the border is cut off
    rounds: int = 2  # GrabCut rounds: the region's seeds, then the strict visual hull's projection
    strict_tolerance: int = 0  # views that may disagree with a voxel of the hull that seeds a round
    min_frames: int = 3
    # the GrabCut masks' outlines moved onto the frames' edges after the last round (.outline); None: kept
    outline: OutlineOptions | None = field(default_factory=OutlineOptions)
    # the ground's photo-consistency (.ground), with a ground plane: pixels differing less than
    # ``ground_below`` (0..255) from the neighbouring frames warped through the plane are sure
    # background; undecided ones (probable either way) differing more than ``object_above``
    # are sure foreground (None: not used). Sure background from the ground cue lost more of the
    # object than it removed of the ground; the object cue at 12 recovers the shadowed parts
    ground_below: float | None = None
    object_above: float | None = 12.0
    ground_neighbours: int = 2  # frames on each side, in capture order, warped onto a frame
    # after the outline: a piece of a mask outside the projection (grown by ``trim_band`` px) of
    # the other frames' hull (``trim_tolerance`` of them may disagree with a voxel) is cut when
    # it reaches ``trim_depth`` (a share of the frame's longer side) beyond it; shallower pieces
    # are mostly the hull's own coarseness (a thin part a voxel misses) and stay (None: no trim)
    trim_tolerance: int | None = 1
    trim_band: int = 2
    trim_depth: float = 0.0125


@dataclass
class MaskReport:
    masks: dict[str, np.ndarray]  # kept frame -> mask (float32 0/1, frame pixels)
    dropped: dict[str, str]  # frame -> why (cut by the border, disagrees with the hull, empty)
    iou: dict[str, float]  # each segmented frame's IoU with the hull of all masks
    region: dict
    method: str
    seconds: float = 0.0

    def summary(self) -> dict:
        values = list(self.iou.values())
        return {"method": self.method, "kept": len(self.masks), "dropped": len(self.dropped),
                "dropped_frames": self.dropped, "mean_iou_with_hull": round(float(np.mean(values)), 4) if values else None,
                "iou_with_hull": {k: round(v, 4) for k, v in self.iou.items()}, "region": self.region,
                "seconds": round(self.seconds, 2)}


def parse_object_box(text: str | None) -> tuple[float, ...] | None:
    """``X0,Y0,Z0,X1,Y1,Z1`` (orbit frame) as six floats with X0 < X1 etc.; InputError else."""
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    require(len(values) == 6 and all(np.isfinite(values)), None, f"--object-box {text} is not six numbers",
            "write X0,Y0,Z0,X1,Y1,Z1, e.g. -0.3,-0.3,-0.3,0.3,0.3,0.3")
    require(all(values[k] < values[k + 3] for k in range(3)), None,
            f"--object-box {text} is empty (each lower corner must be below the upper)",
            "write X0,Y0,Z0,X1,Y1,Z1 with X0 < X1, Y0 < Y1 and Z0 < Z1")
    return values


def _features(sfm, names: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per frame, the observed features' pixels and point indices."""
    obs = np.asarray(sfm.observations).reshape(-1, 4)
    out = {}
    for k, n in enumerate(sfm.names):
        if n in names:
            rows = obs[obs[:, 1] == k]
            out[n] = (rows[:, 2:4], rows[:, 0].astype(np.int64))
    return out


def make_masks(frames: dict[str, np.ndarray], sfm, options: MaskOptions | None = None, emit=None,
               where=None) -> MaskReport:
    """Masks of the registered ``frames`` (name -> RGB uint8) of ``sfm`` (an SfmResult). Raises
    InputError (naming ``where``) when no object can be isolated or too few frames keep a mask."""
    options = options or MaskOptions()
    emit = emit or (lambda *a, **k: None)
    start = time.perf_counter()
    views = [v for v in views_of(sfm) if v.name in frames]
    require(len(views) >= options.min_frames, where,
            f"no object can be isolated: {len(views)} frames with cameras", NO_OBJECT_FIX)
    region = object_region(views, sfm.points, options.object_box, where)
    emit("stage", stage="masks", frames=len(views), **region.summary())
    segmenter = OnnxSegmenter(options.model, options.model_size) if options.model is not None else None
    features = _features(sfm, [v.name for v in views])
    points = np.asarray(sfm.points, np.float64).reshape(-1, 3)
    obj = points[region.inside]
    masks, dropped, fg_of, bg_of = {}, {}, {}, {}
    ground = _ground_differences(views, frames, obj, region, options)
    for v in views:
        uv, _ = v.project(obj)
        hull = hull_polygon(uv)
        if hull is None:
            dropped[v.name] = "no object point in front of the camera"
            continue
        inside = (uv[:, 0] > -v.width) & (uv[:, 0] < 2 * v.width) & (uv[:, 1] > -v.height) & (uv[:, 1] < 2 * v.height)
        lo, hi = np.percentile(uv[inside], [0.5, 99.5], axis=0) if inside.sum() >= 3 else (hull.min(0), hull.max(0))
        edge = options.edge * max(v.width, v.height)
        if lo[0] < edge or lo[1] < edge or hi[0] > v.width - edge or hi[1] > v.height - edge:
            dropped[v.name] = "the object's region leaves the frame"
            continue
        fuv, fid = features.get(v.name, (np.zeros((0, 2)), np.zeros(0, np.int64)))
        fg_of[v.name], bg_of[v.name] = fuv[region.inside[fid]], fuv[region.background[fid]]
        if segmenter is not None:
            masks[v.name] = segmenter(frames[v.name])
        else:
            labels = region_seeds((v.height, v.width), hull, fg_of[v.name], bg_of[v.name], options.seeds)
            _ground_seeds(labels, ground.get(v.name), options)
            masks[v.name] = grabcut(frames[v.name], labels, options.seeds.iterations, fg_of[v.name],
                                        options.seeds.smooth)
    rounds = 1 if segmenter is not None else options.rounds
    scores = {}
    for r in range(rounds):
        votes = _votes(views, masks, obj, options)
        tolerance = max(1, int(round(options.tolerance_share * len(masks))))
        hull3d = votes.hull(tolerance=tolerance)
        scores = {v.name: iou(masks[v.name], project_hull(hull3d, v)) for v in views if v.name in masks}
        if r + 1 == rounds:
            break
        # the next round is seeded by the strict hull of the frames that agree with the tolerant
        # one, each frame's without its own mask (see .consistency)
        confident = [n for n in masks if scores[n] >= options.min_iou]
        if len(confident) < options.min_frames:
            break
        for v in views:
            if v.name in masks:
                strict = votes.hull(confident, options.strict_tolerance, exclude=v.name)
                bound = project_hull(strict, v)
                if not bound.any():
                    continue
                voxel_px = strict.voxel * v.fx / max(float(np.linalg.norm(v.centre - obj.mean(0))), 1e-9)
                labels = mask_seeds((v.height, v.width), bound, max(3, int(round(2 * voxel_px))), masks[v.name])
                _ground_seeds(labels, ground.get(v.name), options)
                masks[v.name] = grabcut(frames[v.name], labels, options.seeds.iterations, fg_of[v.name],
                                        options.seeds.smooth)
    if segmenter is None and options.outline is not None:
        for v in views:
            if v.name in masks:
                masks[v.name] = refine_outline(frames[v.name], masks[v.name], options.outline, fg_of[v.name])
    if options.trim_tolerance is not None and len(masks) > options.min_frames:
        votes = _votes(views, masks, obj, options)
        for v in views:
            if v.name in masks:
                others = votes.hull(tolerance=options.trim_tolerance, exclude=v.name)
                if not others.empty:
                    masks[v.name] = trim_outside(masks[v.name], project_hull(others, v), options.trim_band,
                                                 options.trim_depth * max(v.width, v.height))
    for n in list(masks):
        if not masks[n].any():
            dropped[n] = "empty mask"
        elif scores[n] < options.min_iou:
            dropped[n] = f"disagrees with the other frames' visual hull (IoU {scores[n]:.2f})"
        if n in dropped:
            del masks[n]
    if len(masks) < options.min_frames:
        raise InputError(where, f"no object can be isolated: {len(masks)} of {len(views)} frames kept a "
                         "consistent mask", NO_OBJECT_FIX)
    report = MaskReport(masks, dropped, scores, region.summary(), "onnx" if segmenter else "grabcut",
                        time.perf_counter() - start)
    emit("masks", kept=len(masks), dropped=len(dropped), mean_iou_with_hull=report.summary()["mean_iou_with_hull"],
         method=report.method)
    return report


def trim_outside(mask: np.ndarray, hull: np.ndarray, band: int, depth_px: float) -> np.ndarray:
    """``mask`` less its connected pieces outside ``hull`` (a projection, grown by ``band`` px)
    that reach ``depth_px`` or more beyond it (float32 0/1)."""
    import cv2  # bpy must be imported before cv2 in one process

    m = np.asarray(mask) > 0.5
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band + 1, 2 * band + 1))
    outside = (m & ~(cv2.dilate((np.asarray(hull) > 0.5).astype(np.uint8), kernel) > 0)).astype(np.uint8)
    n, pieces = cv2.connectedComponents(outside, connectivity=8)
    if n > 1:
        depth = cv2.distanceTransform(outside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        reach = np.zeros(n, np.float32)
        np.maximum.at(reach, pieces.ravel(), depth.ravel())
        deep = np.nonzero(reach >= depth_px)[0]
        m &= ~np.isin(pieces, deep[deep > 0])
    return m.astype(np.float32)


def _votes(views: list[View], masks: dict[str, np.ndarray], obj: np.ndarray, options: MaskOptions) -> Votes:
    """The masks' votes on a box round the object points, grown by half its size."""
    lo, hi = obj.min(0), obj.max(0)
    grow = 0.5 * float(np.max(hi - lo))
    return Votes(views, masks, lo - grow, hi + grow, options.grid)


def _ground_differences(views: list[View], frames: dict[str, np.ndarray], obj: np.ndarray, region: Region,
                        options: MaskOptions) -> dict[str, np.ndarray]:
    """Per frame, the ground's photo-consistency difference (.ground); none without a ground
    plane or when neither threshold is set."""
    if region.ground is None or (options.ground_below is None and options.object_above is None):
        return {}
    centre, size = obj.mean(0), 2.0 * float(np.ptp(obj, 0).max())
    out, k = {}, options.ground_neighbours
    for i, v in enumerate(views):
        others = [views[j] for j in range(i - k, i + k + 1) if j != i and 0 <= j < len(views)]
        out[v.name] = ground_difference(frames[v.name], v, [(frames[o.name], o) for o in others], region.ground,
                                        centre, size)
    return out


def _ground_seeds(labels: np.ndarray, difference: np.ndarray | None, options: MaskOptions) -> None:
    """Sure labels from the ground difference, in place (see MaskOptions). Each cue is opened
    (eroded, then dilated, by a 7-pixel disk) first: specks of the object that happen to match
    the ground (or of the ground that an occlusion makes differ) would punch holes in a mask,
    and a mask with holes carves every other frame's hull."""
    import cv2  # bpy must be imported before cv2 in one process

    if difference is None:
        return
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))

    def opened(cue):
        return cv2.morphologyEx(cue.astype(np.uint8), cv2.MORPH_OPEN, kernel) > 0

    if options.object_above is not None:
        cue = opened((difference > options.object_above) & np.isfinite(difference))
        labels[cue & ((labels == cv2.GC_PR_FGD) | (labels == cv2.GC_PR_BGD))] = cv2.GC_FGD
    if options.ground_below is not None:
        labels[opened(difference < options.ground_below) & (labels != cv2.GC_FGD)] = cv2.GC_BGD
