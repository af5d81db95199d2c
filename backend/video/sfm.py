"""Cameras by structure from motion (pycolmap, CPU): one shared camera with radial distortion.

Steps: feature images (grey, contrast-stretched, resized so the longer side is at least
``min_feature_size``: SIFT finds little on small or dim frames), SIFT with affine shape and
domain-size pooling (wide baselines; the strongest ``max_features`` a frame), guided matching
of every pair for up to ``exhaustive_up_to`` frames, else of a cyclic window (an orbit ends
where it began), incremental mapping with distortion held at zero, then models that share two or more
frames are merged (incremental mapping splits a ring where consecutive views share no
three-view tracks), global mapping as the fallback, and a final re-triangulation and bundle
adjustment that also refines the distortion; with masks, one more adjustment that adds the
silhouettes' epipolar tangencies (``silhouettes``). Poses are world-to-camera in OpenCV axes,
intrinsics in the input frames' pixels (COLMAP's corner-origin convention, like ours).

The principal point is held at the frame centre: a narrow lens cannot observe it (it trades
with the cameras' rotations). A ring of few views with short tracks leaves a flat valley in
the reprojection error that known intrinsics and further adjustment rounds do not remove;
the masks' silhouettes pin it (``silhouettes``). Longer than 400 lines: the SfM steps share
one options record and pycolmap's state, and read best in one place."""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from ..capture.images import read_mask
from ..errors import InputError
from .silhouettes import SilhouetteOptions
from .silhouettes import refine as refine_with_silhouettes

# COLMAP camera models with one shared camera: their distortion parameter names (OpenCV's).
CAMERA_MODELS = {"SIMPLE_RADIAL": ("k1",), "RADIAL": ("k1", "k2"), "OPENCV": ("k1", "k2", "p1", "p2")}


MAX_POINT_ERROR = 4.0  # feature image pixels (COLMAP's filter_max_reproj_error)


@dataclass
class SfmOptions:
    camera_model: str = "SIMPLE_RADIAL"
    min_feature_size: int = 1024  # feature images' longer side is at least this (upscaled)...
    max_feature_size: int = 2048  # ...and at most this (downscaled)
    # SIFT keeps the strongest this many per frame: CPU matching time grows with its square
    max_features: int = 4096
    peak_threshold: float = 0.002  # SIFT contrast threshold on the stretched grey image
    max_ratio: float = 0.85  # Lowe's ratio test (COLMAP's 0.8 loses the few matches wide baselines give)
    # match all pairs up to this many frames, else a cyclic window (matching is most of the
    # SfM time on a CPU)
    exhaustive_up_to: int = 24
    window: int = 10  # neighbours each frame is matched with when not exhaustive
    min_registered_share: float = 0.3  # fewer registered frames than this share is a failure
    threads: int = -1
    seed: int = 0
    silhouettes: SilhouetteOptions = field(default_factory=SilhouetteOptions)


@dataclass
class SfmResult:
    names: list[str]  # every input frame, in order
    poses: dict[str, np.ndarray]  # registered frame -> 3x4 world-to-camera [R|t], OpenCV axes
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: dict[str, float]  # OpenCV names (k1, k2, p1, p2)
    points: np.ndarray  # (N, 3) sparse points, SfM world
    reprojection_error_px: float  # mean, in input frame pixels
    method: str  # "incremental", "incremental+merge" or "global"
    seconds: dict[str, float] = field(default_factory=dict)
    # (M, 4) observations of the points: point index, frame index in names, x, y (frame pixels)
    observations: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    silhouettes: dict = field(default_factory=dict)  # what the silhouette refinement did (silhouettes.refine)

    @property
    def registered(self) -> int:
        return len(self.poses)

    @property
    def total(self) -> int:
        return len(self.names)

    def summary(self) -> dict:
        return {"registered": self.registered, "total": self.total,
                "reprojection_error_px": round(self.reprojection_error_px, 4), "method": self.method,
                "camera": {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                           "distortion": self.distortion},
                "points": int(len(self.points)), "seconds": {k: round(v, 2) for k, v in self.seconds.items()},
                "silhouettes": self.silhouettes}


@contextlib.contextmanager
def _quiet_colmap():
    import pycolmap  # here: slow to load, and only capture-from-video needs it

    before = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 3  # fatal only: progress lines would flood stderr, and failures are ours to report
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = before


def feature_scale(width: int, height: int, options: SfmOptions) -> float:
    """Resize factor from frames to feature images."""
    longer = max(width, height)
    return min(max(longer, options.min_feature_size), options.max_feature_size) / longer


def write_feature_images(frames: list[Path], folder: Path, scale: float) -> tuple[int, int]:
    """Grey copies of the frames, resized by ``scale`` and stretched (1st..99.5th percentile
    to black..white) so dim footage gives SIFT contrast. Returns the feature image size."""
    folder.mkdir(parents=True, exist_ok=True)
    size = None
    for path in frames:
        with Image.open(path) as im:
            grey = im.convert("L")
            size = (max(1, round(grey.width * scale)), max(1, round(grey.height * scale)))
            if size != grey.size:
                grey = grey.resize(size, Image.BICUBIC if scale > 1 else Image.LANCZOS)
        a = np.asarray(grey, np.float32)
        lo, hi = np.percentile(a, [1.0, 99.5])
        a = np.clip((a - lo) / max(hi - lo, 1.0), 0.0, 1.0)
        Image.fromarray(np.round(a * 255).astype(np.uint8)).save(folder / f"{path.stem}.png")
    return size


def image_pairs(names: list[str], options: SfmOptions) -> list[tuple[str, str]]:
    """Every pair for short sequences; else each frame with its ``window`` successors and with
    frames 2^k ahead, wrapping around (so the end of an orbit meets its start)."""
    n = len(names)
    if n <= options.exhaustive_up_to:
        return [(names[i], names[j]) for i in range(n) for j in range(i + 1, n)]
    offsets = set(range(1, options.window + 1)) | {2 ** k for k in range(int(math.log2(n)))}
    pairs = set()
    for i in range(n):
        for d in offsets:
            j = (i + d) % n
            if j != i:
                pairs.add((min(i, j), max(i, j)))
    return [(names[i], names[j]) for i, j in sorted(pairs)]


def _mapper_options(options: SfmOptions):
    import pycolmap  # here: slow to load, and only capture-from-video needs it

    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = options.threads
    opts.random_seed = options.seed
    opts.mapper.random_seed = options.seed
    opts.min_model_size = 3
    # Distortion is refined once at the end: small partial models of a narrow lens drift to
    # absurd k1 values when it is free, and then no longer join.
    opts.ba_refine_extra_params = False
    opts.mapper.abs_pose_refine_extra_params = False
    # Sparse views of weakly textured objects give few 2D-3D matches per new frame.
    opts.mapper.abs_pose_min_num_inliers = 15
    opts.mapper.abs_pose_min_inlier_ratio = 0.15
    return opts


def _poses(rec) -> dict[int, np.ndarray]:
    return {im.image_id: im.cam_from_world().matrix() for im in rec.images.values() if im.has_pose}


def _similarity(target: dict[int, np.ndarray], source: dict[int, np.ndarray]):
    """(s, R, t) with x_target = s R x_source + t from the frames both models hold, or None
    when they share fewer than two frames or disagree (rotation > 10 deg, centre > 10%)."""
    common = sorted(set(target) & set(source))
    if len(common) < 2:
        return None
    u, _, vt = np.linalg.svd(sum(target[i][:, :3].T @ source[i][:, :3] for i in common))
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    ca = np.array([-target[i][:, :3].T @ target[i][:, 3] for i in common])
    cb = np.array([-source[i][:, :3].T @ source[i][:, 3] for i in common])
    ma, mb = ca.mean(0), cb.mean(0)
    spread = float(np.sum((cb - mb) ** 2))
    s = float(np.sum((ca - ma) * ((cb - mb) @ R.T)) / spread) if spread > 0 else 0.0
    if s <= 0:
        return None
    t = ma - s * R @ mb
    extent = max(np.linalg.norm(-p[:, :3].T @ p[:, 3] - ma) for p in target.values())
    for i, a, b in zip(common, ca, cb):
        cos = (np.trace(target[i][:, :3] @ (source[i][:, :3] @ R.T).T) - 1) / 2
        if np.degrees(np.arccos(np.clip(cos, -1, 1))) > 10 or np.linalg.norm(s * R @ b + t - a) > 0.1 * extent:
            return None
    return s, R, t


def merge_models(models: list) -> tuple[dict[int, np.ndarray], int]:
    """Poses of the largest model, with every model that shares two or more frames with it
    brought in by a similarity (repeated until nothing joins). Returns (poses, models used).

    Partial models of a narrow lens disagree on the focal length (it trades against depth),
    which bends them; each is first re-adjusted with the models' median focal length held."""
    ordered = sorted(models, key=lambda r: -r.num_reg_images())
    if len(ordered) > 1:
        focal = float(np.median([_focal(r) for r in ordered]))
        for rec in ordered:
            camera = next(iter(rec.cameras.values()))
            camera.params = _with_focal(camera, focal)
            _adjust(rec, focal=False, distortion=False)
    merged = _poses(ordered[0])
    pending = [_poses(r) for r in ordered[1:]]
    used = 1
    joined = True
    while joined and pending:
        joined = False
        for other in list(pending):
            fit = _similarity(merged, other)
            if fit is None:
                continue
            s, R, t = fit
            for i, P in other.items():
                if i not in merged:
                    Rn = P[:, :3] @ R.T
                    centre = s * R @ (-P[:, :3].T @ P[:, 3]) + t
                    merged[i] = np.c_[Rn, -Rn @ centre]
            pending.remove(other)
            used += 1
            joined = True
    return merged, used


def _focal(rec) -> float:
    camera = next(iter(rec.cameras.values()))
    return float(np.sqrt(camera.focal_length_x * camera.focal_length_y))


def _with_focal(camera, focal: float) -> np.ndarray:
    params = np.array(camera.params, np.float64)
    for i in camera.focal_length_idxs():
        params[i] = focal
    return params


def _adjust(rec, focal: bool, distortion: bool) -> None:
    """Bundle adjustment of all poses and points (Cauchy loss, gauge fixed by two cameras)."""
    import pycolmap  # here: slow to load, and only capture-from-video needs it

    options = pycolmap.BundleAdjustmentOptions()
    options.print_summary = False
    options.refine_focal_length = focal
    options.refine_extra_params = distortion
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    pycolmap.create_default_bundle_adjuster(options, config, rec).solve()


def _rebuild(db_path: Path, camera, poses: dict[int, np.ndarray]):
    """A reconstruction with the given poses and no points (to triangulate)."""
    import pycolmap  # here: slow to load, and only capture-from-video needs it

    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(camera)
    with pycolmap.Database.open(db_path) as db:
        for image_id, P in sorted(poses.items()):
            name = db.read_image(image_id).name
            keypoints = db.read_keypoints(image_id)[:, :2].astype(np.float64)
            image = pycolmap.Image(name=name, keypoints=keypoints, camera_id=camera.camera_id, image_id=image_id)
            rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(P))
    return rec


def _refine(rec, db_path: Path, image_dir: Path, out: Path, options: SfmOptions):
    """Re-triangulate every match with the poses held (two-view tracks too: they are what
    holds a frame at a weak link), then bundle-adjust: first with the intrinsics held
    (joined models settle), then everything, distortion included."""
    import pycolmap  # here: slow to load, and only capture-from-video needs it

    out.mkdir(parents=True, exist_ok=True)
    triangulation = _mapper_options(options)
    triangulation.triangulation.ignore_two_view_tracks = False
    rec = pycolmap.triangulate_points(rec, db_path, image_dir, out, True, triangulation, False)
    _adjust(rec, focal=False, distortion=False)
    _adjust(rec, focal=True, distortion=True)
    rec.update_point_3d_errors()
    drop_outliers(rec, MAX_POINT_ERROR)
    return rec


def drop_outliers(rec, max_error: float) -> int:
    """Delete points whose mean reprojection error (feature image pixels) is above
    ``max_error`` or not finite: features on a distant background (an environment seen at
    infinity) can end up triangulated behind the cameras after adjustment, with errors of
    1e150 px that would swamp the mean and the scene frame. Returns how many went."""
    bad = [i for i, p in rec.points3D.items()
           if not (np.isfinite(p.error) and p.error <= max_error and np.all(np.isfinite(p.xyz)))]
    for i in bad:
        rec.delete_point3D(i)
    return len(bad)


def solve(frames: list[Path], workdir: Path, options: SfmOptions | None = None, emit=None,
          source: Path | None = None, masks: list[Path] | None = None) -> SfmResult:
    """Cameras for ``frames`` (image files of one size, in capture order). ``workdir`` holds
    the feature images and the COLMAP database. With ``masks`` (one per frame) the cameras are
    refined by silhouette coherence (``silhouettes.refine``). Raises InputError when fewer than
    ``min_registered_share`` of the frames register; ``source`` names the input in that error."""
    import pycolmap  # here: slow to load, and only capture-from-video needs it

    options = options or SfmOptions()
    emit = emit or (lambda *a, **k: None)
    if options.camera_model not in CAMERA_MODELS:
        raise ValueError(f"camera model {options.camera_model} is not one of {sorted(CAMERA_MODELS)}")
    with Image.open(frames[0]) as im:
        width, height = im.size
    names = [p.stem for p in frames]
    seconds = {}
    tick = time.perf_counter()
    scale = feature_scale(width, height, options)
    feature_dir, db_path = workdir / "features", workdir / "database.db"
    fw, fh = write_feature_images(frames, feature_dir, scale)
    files = [f"{n}.png" for n in names]
    pycolmap.set_random_seed(options.seed)
    with _quiet_colmap():
        emit("stage", stage="features", frames=len(frames), feature_size=[fw, fh])
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = options.camera_model
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = options.threads
        extraction.max_image_size = max(fw, fh)
        extraction.sift.peak_threshold = options.peak_threshold
        extraction.sift.max_num_features = options.max_features
        extraction.sift.estimate_affine_shape = True
        extraction.sift.domain_size_pooling = True
        pycolmap.extract_features(db_path, feature_dir, image_names=files, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
        seconds["features"] = time.perf_counter() - tick

        tick = time.perf_counter()
        pairs = image_pairs(files, options)
        emit("stage", stage="matching", pairs=len(pairs))
        pairs_path = workdir / "pairs.txt"
        pairs_path.write_text("".join(f"{a} {b}\n" for a, b in pairs))
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = options.threads
        matching.guided_matching = True
        matching.sift.max_ratio = options.max_ratio
        pairing = pycolmap.ImportedPairingOptions()
        pairing.match_list_path = pairs_path
        verification = pycolmap.TwoViewGeometryOptions()
        verification.ransac.random_seed = options.seed
        verification.ransac.max_num_trials = 2000  # pairs that do not overlap would spend 10000 each
        pycolmap.match_image_pairs(db_path, matching_options=matching, pairing_options=pairing,
                                   verification_options=verification, device=pycolmap.Device.cpu)
        seconds["matching"] = time.perf_counter() - tick

        tick = time.perf_counter()
        emit("stage", stage="mapping")
        need = max(3, math.ceil(options.min_registered_share * len(frames)))
        (workdir / "incremental").mkdir(exist_ok=True)
        models = pycolmap.incremental_mapping(db_path, feature_dir, workdir / "incremental",
                                              _mapper_options(options))
        method, poses, camera = "incremental", {}, None
        if models:
            poses, used = merge_models(list(models.values()))
            camera = next(iter(max(models.values(), key=lambda r: r.num_reg_images()).cameras.values()))
            method = "incremental+merge" if used > 1 else "incremental"
        if len(poses) < need:
            glob = pycolmap.GlobalPipelineOptions()
            glob.num_threads = options.threads
            glob.random_seed = options.seed
            (workdir / "global").mkdir(exist_ok=True)
            found = pycolmap.global_mapping(db_path, feature_dir, workdir / "global", glob)
            best = max(found.values(), key=lambda r: r.num_reg_images(), default=None)
            if best is not None and best.num_reg_images() > len(poses):
                poses, camera, method = _poses(best), next(iter(best.cameras.values())), "global"
        seconds["mapping"] = time.perf_counter() - tick
        if len(poses) < need:
            raise InputError(source or frames[0].parent,
                             f"structure from motion registered only {len(poses)} of {len(frames)} frames "
                             f"(at least {need} needed)",
                             "film a textured, well-lit scene around the object (e.g. a newspaper under it), "
                             "move slower so frames overlap, or give more frames with --frames")

        tick = time.perf_counter()
        emit("stage", stage="refine", registered=len(poses))
        rec = _refine(_rebuild(db_path, camera, poses), db_path, feature_dir, workdir / "refined", options)
        seconds["refine"] = time.perf_counter() - tick
        error = float(rec.compute_mean_reprojection_error())
    result = _result(rec, names, width, height, fw / width, fh / height, error, method, seconds)
    if masks is not None:
        tick = time.perf_counter()
        emit("stage", stage="silhouettes")
        result, result.silhouettes = refine_with_silhouettes(
            result, {n: read_mask(m) for n, m in zip(names, masks)}, options.silhouettes)
        result.seconds["silhouettes"] = time.perf_counter() - tick
    return result


def _result(rec, names, width, height, sx, sy, error, method, seconds) -> SfmResult:
    """The reconstruction in input frame pixels (feature images were resized by sx, sy)."""
    camera = next(iter(rec.cameras.values()))
    model = camera.model.name
    keys = CAMERA_MODELS[model]
    distortion = {k: float(v) for k, v in zip(keys, np.asarray(camera.params)[-len(keys):])}
    fx, fy = camera.focal_length_x, camera.focal_length_y
    cx, cy = camera.principal_point_x, camera.principal_point_y
    poses = {im.name.rsplit(".", 1)[0]: im.cam_from_world().matrix() for im in rec.images.values() if im.has_pose}
    points = np.array([p.xyz for p in rec.points3D.values()], np.float64).reshape(-1, 3)
    frame_of = {image_id: names.index(im.name.rsplit(".", 1)[0]) for image_id, im in rec.images.items()}
    observations = [(k, frame_of[e.image_id], *rec.images[e.image_id].points2D[e.point2D_idx].xy)
                    for k, p in enumerate(rec.points3D.values()) for e in p.track.elements]
    observations = np.array(observations, np.float64).reshape(-1, 4) / [1, 1, sx, sy]
    return SfmResult(names=names, poses=poses, width=width, height=height, fx=fx / sx, fy=fy / sy,
                     cx=cx / sx, cy=cy / sy, distortion=distortion, points=points, observations=observations,
                     reprojection_error_px=error / math.sqrt(sx * sy), method=method, seconds=seconds)
