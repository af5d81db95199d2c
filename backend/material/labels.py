"""Material labels: per-pixel material masks (given or clustered) -> per-face labels.

Masks are checked before any work: one per frame or none, the frame's size, no overlap
between per-material masks, every object pixel labelled. Per-face labels are the majority
vote over the views that see the face's centroid (visibility by ray casting); the share of
votes that disagree with the majority is reported."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image
from scipy import sparse
from scipy.cluster.vq import kmeans2

from ..capture.images import linear_to_srgb, read_linear_rgb, read_mask
from ..capture.model import Camera, Capture
from ..errors import InputError, require
from ..fsio import atomic_dir
from ..geometry.mesh import Mesh
from ..geometry.raycast import RayCaster
from .meshcolors import unique_edges

OBJECT_THRESHOLD = 0.5
# k-means runs from this many k-means++ starts and keeps the lowest within-cluster variance: one
# start can settle where one paint is split by brightness and two others are merged (a red wall
# in two halves, the blue wall with the grey floor), and the merged paints' one constant then
# matches neither colour
KMEANS_STARTS = 8


def read_label_image(path: str | Path) -> np.ndarray:
    """An 8-bit label PNG as an integer (H, W) array (grey, palette or equal-channel RGB)."""
    path = Path(path)
    require(path.is_file(), path, "material mask not found", "check the path in capture.json")
    try:
        with Image.open(path) as im:
            im.load()
            arr = np.asarray(im)
    except Exception as err:
        raise InputError(path, f"cannot read material mask ({err.__class__.__name__})",
                         "write an 8-bit PNG of integer labels") from err
    if arr.ndim == 3:
        equal = np.all(arr[..., :3] == arr[..., :1], axis=-1).all()
        require(bool(equal), path, "material mask is a colour image",
                "write one integer label per pixel as an 8-bit greyscale PNG (0 = unassigned)")
        arr = arr[..., 0]
    return arr.astype(np.int64)


def combine_binary_masks(name: str, masks: list[np.ndarray], path=None) -> np.ndarray:
    """Per-material binary masks of one frame -> a label image 1..n; overlaps are rejected."""
    stack = np.stack([np.asarray(m) > OBJECT_THRESHOLD for m in masks])
    overlap = int((stack.sum(0) > 1).sum())
    require(overlap == 0, path, f"frame {name}: {overlap} pixels belong to more than one material mask",
            "make the per-material masks disjoint")
    return (stack * np.arange(1, len(masks) + 1)[:, None, None]).sum(0)


def check_labels(name: str, labels: np.ndarray, size: tuple[int, int], object_mask: np.ndarray | None,
                 path=None) -> None:
    """One frame's label image against its frame size and object mask."""
    w, h = size
    require(labels.shape == (h, w), path,
            f"frame {name}: material mask is {labels.shape[1]}x{labels.shape[0]} but the frame is {w}x{h}",
            "resize the material mask to the frame")
    if object_mask is not None:
        missing = int(((object_mask >= OBJECT_THRESHOLD) & (labels <= 0)).sum())
        require(missing == 0, path, f"frame {name}: {missing} object pixels have no material label",
                "label every pixel inside the object mask (0 = unassigned is for the background)")


def load_material_labels(capture: Capture) -> list[np.ndarray] | None:
    """Validated per-frame label images from ``frame.material_mask`` (None when none given)."""
    given = [f for f in capture.frames if f.material_mask is not None]
    if not given:
        return None
    lacking = next((f for f in capture.frames if f.material_mask is None), None)
    require(lacking is None, lacking.image if lacking else None,
            f"frame {lacking.name if lacking else ''} has no material_mask but {len(given)} of "
            f"{len(capture.frames)} frames do", "give a material mask for every frame or for none")
    out = []
    for f in capture.frames:
        labels = read_label_image(f.material_mask)
        obj = read_mask(f.mask) if f.mask is not None else None
        check_labels(f.name, labels, (f.camera.width, f.camera.height), obj, f.material_mask)
        out.append(labels)
    return out


def check_label_set(names: list[str], labels: list[np.ndarray], sizes: list[tuple[int, int]],
                    object_masks: list[np.ndarray | None] | None = None) -> None:
    """In-memory label images against the frames (count, size, coverage)."""
    require(len(labels) == len(names), None, f"{len(labels)} material masks for {len(names)} frames "
            f"(frame {names[min(len(labels), len(names) - 1)]} has none or too many)",
            "give one material mask per frame")
    for i, name in enumerate(names):
        check_labels(name, labels[i], sizes[i], None if object_masks is None else object_masks[i])


def kmeans(points: np.ndarray, k: int, rng: np.random.Generator, iterations: int = 25,
           starts: int = KMEANS_STARTS) -> tuple[np.ndarray, np.ndarray, float]:
    """k-means of ``points`` (N, D): the (centres, labels, inertia) of the best of ``starts``
    k-means++ starts (the lowest sum of squared distances to the centres)."""
    best = None
    for _ in range(starts):
        centres, label = kmeans2(points, k, iter=iterations, minit="++", missing="warn", seed=rng)
        inertia = float(((points - centres[label]) ** 2).sum())
        if best is None or inertia < best[2]:
            best = (centres, label, inertia)
    return best


def cluster_labels(images: list[np.ndarray], object_masks: list[np.ndarray], k: int, seed: int = 0,
                   iterations: int = 25, max_pixels: int = 200_000) -> list[np.ndarray]:
    """Label images 1..k by k-means on object-pixel chromaticity and log brightness (0 = background),
    clustered jointly over all frames so labels agree between views; labels sorted by brightness."""
    feats, where = [], []
    for img, m in zip(images, object_masks):
        obj = m >= OBJECT_THRESHOLD
        feats.append(_colour_features(np.asarray(img, np.float64)[obj]))
        where.append(obj)
    allf = np.concatenate(feats)
    rng = np.random.default_rng(seed)
    sub = allf[rng.choice(len(allf), min(len(allf), max_pixels), replace=False)]
    centres, _, _ = kmeans(sub, k, rng, iterations)
    order = np.argsort(np.argsort(centres[:, 2]))  # label 1 = darkest
    out = []
    for f, obj in zip(feats, where):
        lab = np.zeros(obj.shape, np.int64)
        lab[obj] = order[((f[:, None] - centres[None]) ** 2).sum(-1).argmin(1)] + 1
        out.append(lab)
    return out


def choose_material_count(images: list[np.ndarray], object_masks: list[np.ndarray] | None, most: int = 4,
                          gain: float = 0.25, seed: int = 0, max_pixels: int = 50_000) -> int:
    """How many materials the frames' object colours show: the smallest k after which one more
    cluster no longer leaves less than ``gain`` of the within-cluster variance, k-means on the
    object pixels' chromaticity alone (:func:`chromaticity`). A per-pixel brightness scale
    (shading, a lamp's falloff, a texture's light and dark) leaves chromaticity unchanged, so
    it cannot pose as a second paint, nor spread two paints' lumps until they read as one;
    :func:`cluster_labels`, given a count, still clusters with log brightness. One material
    spreads its chromaticities in one lump (two means leave 68 % of a round 2-D Gaussian's
    variance) and stays at one; distinct paints leave far less at their count. Paints that
    differ in brightness only (white and black) are one material here. Pixels darker than
    ``DARK_SHARE`` of the bright end (the 90th percentile of r + g + b) are left out: their
    chromaticity is mostly noise and quantisation. A spread in chromaticity under
    ``CHROMA_SPREAD`` (root mean square) is one material."""
    if object_masks is None:
        return 1
    rgb = np.concatenate([np.asarray(img, np.float64)[..., :3][m >= OBJECT_THRESHOLD]
                          for img, m in zip(images, object_masks)])
    if len(rgb) < 10 * most:
        return 1
    s = rgb.sum(-1)
    rgb = rgb[s >= DARK_SHARE * np.percentile(s, 90)]
    if len(rgb) < 10 * most:
        return 1
    feats = chromaticity(rgb)
    rng = np.random.default_rng(seed)
    sub = feats[rng.choice(len(feats), min(len(feats), max_pixels), replace=False)]
    inertia = [float(((sub - sub.mean(0)) ** 2).sum())]
    if inertia[0] < len(sub) * CHROMA_SPREAD ** 2:
        return 1
    for k in range(2, most + 1):
        inertia.append(kmeans(sub, k, rng)[2])
    k = 1
    while k < most and inertia[k] < gain * inertia[k - 1]:
        k += 1
    return k


# choose_material_count: pixels below this share of the bright end's r + g + b are not counted
# (a dark pixel's chromaticity is a ratio of small, noisy values), and a chromaticity spread
# (RMS) below CHROMA_SPREAD is one paint (k-means would otherwise split rounding noise)
DARK_SHARE = 0.2
CHROMA_SPREAD = 0.01


def chromaticity(rgb: np.ndarray) -> np.ndarray:
    """(N, 3) linear RGB -> (N, 2) chromaticity (r, g) / (r + g + b): unchanged by any per-pixel
    brightness scale."""
    s = np.maximum(rgb.sum(-1, keepdims=True), 1e-6)
    return rgb[:, :2] / s


def _colour_features(rgb: np.ndarray) -> np.ndarray:
    s = np.maximum(rgb.sum(-1, keepdims=True), 1e-6)
    return np.concatenate([rgb[:, :2] / s, 0.15 * np.log(s / 3 + 1e-3)], 1)


@dataclass
class FaceLabels:
    labels: np.ndarray  # (F,) 0 .. n_materials - 1
    material_ids: list[int]  # the mask label value of each material
    disagreement: float  # share of votes that disagree with their face's majority
    votes: int
    unseen_faces: int  # faces no view saw, labelled from their neighbours

    @property
    def n_materials(self) -> int:
        return len(self.material_ids)


def visible_centroids(mesh: Mesh, camera: Camera, caster: RayCaster | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (F, 2) of face centroids and whether each is seen by the camera
    (in front, inside the image, first hit along the ray from the camera centre)."""
    caster = caster or RayCaster(mesh)
    centroids = mesh.vertices[mesh.faces].mean(1)
    uv, depth = camera.project(centroids)
    inside = (depth > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] < camera.height)
    d = centroids - camera.centre
    dist = np.linalg.norm(d, axis=1)
    d = d / np.maximum(dist, 1e-30)[:, None]
    hits = caster.intersect(camera.centre, d)
    first = hits.hit & ((hits.face == np.arange(mesh.n_faces)) | (hits.distance >= dist * (1 - 1e-4)))
    return uv, inside & first


def vote_face_labels(mesh: Mesh, cameras: list[Camera], label_images: list[np.ndarray]) -> FaceLabels:
    """Per-face material labels by majority vote of the views that see each face's centroid."""
    ids = sorted(set(np.unique(np.concatenate([np.unique(li) for li in label_images]))) - {0})
    if not ids:
        ids = [1]
    lut = np.full(max(ids) + 1, -1, np.int64)
    lut[ids] = np.arange(len(ids))
    counts = np.zeros((mesh.n_faces, len(ids)), np.int64)
    caster = RayCaster(mesh)
    for cam, li in zip(cameras, label_images):
        uv, seen = visible_centroids(mesh, _at_size(cam, li.shape[1], li.shape[0]), caster)
        f = np.flatnonzero(seen)
        lab = li[uv[f, 1].astype(np.int64), uv[f, 0].astype(np.int64)]
        keep = lab > 0
        np.add.at(counts, (f[keep], lut[lab[keep]]), 1)
    votes = int(counts.sum())
    labels = counts.argmax(1)
    seen = counts.sum(1) > 0
    disagreement = 1.0 - counts.max(1).sum() / votes if votes else 0.0
    labels = _fill_unseen(mesh, labels, seen)
    return FaceLabels(labels, [int(i) for i in ids], float(disagreement), votes, int((~seen).sum()))


def _at_size(camera: Camera, width: int, height: int) -> Camera:
    """``camera`` for an image of ``width`` x ``height`` pixels (the label images keep the
    capture's size while the optimiser's cameras may be scaled down)."""
    if (camera.width, camera.height) == (width, height):
        return camera
    sx, sy = width / camera.width, height / camera.height
    return Camera(width, height, camera.fx * sx, camera.fy * sy, camera.cx * sx, camera.cy * sy,
                  camera.camera_to_world.copy(), dict(camera.distortion))


def _fill_unseen(mesh: Mesh, labels: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Give faces no view saw the most common label among their labelled edge neighbours."""
    _, face_edges = unique_edges(mesh.faces)
    F = mesh.n_faces
    incidence = sparse.csr_matrix((np.ones(3 * F), (np.repeat(np.arange(F), 3), face_edges.ravel())))
    adjacency = (incidence @ incidence.T).tocsr()
    labels, known = labels.copy(), seen.copy()
    n = int(labels.max()) + 1
    while not known.all():
        onehot = sparse.csr_matrix((known.astype(float), (np.arange(F), labels)), shape=(F, n))
        counts = (adjacency @ onehot).toarray()
        grow = ~known & (counts.sum(1) > 0)
        if not grow.any():
            labels[~known] = 0
            break
        labels[grow] = counts[grow].argmax(1)
        known |= grow
    return labels


def face_labels(mesh: Mesh, cameras: list[Camera], label_images: list[np.ndarray] | None = None,
                images: list[np.ndarray] | None = None, object_masks: list[np.ndarray] | None = None,
                n_materials: int = 1, seed: int = 0) -> FaceLabels:
    """Per-face labels from the capture's material masks (``load_material_labels``), else from
    clustering the frames' colours into ``n_materials``, else one material for every face."""
    if label_images is None:
        if n_materials <= 1:
            return FaceLabels(np.zeros(mesh.n_faces, np.int64), [1], 0.0, 0, 0)
        label_images = cluster_labels(images, object_masks, n_materials, seed)
    return vote_face_labels(mesh, cameras, label_images)


PALETTE = np.array([[230, 25, 75], [60, 180, 75], [255, 225, 25], [0, 130, 200], [245, 130, 48], [145, 30, 180],
                    [70, 240, 240], [240, 50, 230]], np.float64)  # label 1, 2, ... (cycled)


def label_overlay(rgb: np.ndarray, labels: np.ndarray, alpha: float = 0.6) -> np.ndarray:
    """``rgb`` (uint8) with each labelled pixel blended by ``alpha`` towards its label's
    :data:`PALETTE` colour; background (label 0) darkened to a third."""
    out = np.asarray(rgb, np.float64)[..., :3] / 3.0
    obj = labels > 0
    colour = PALETTE[(labels[obj] - 1) % len(PALETTE)]
    out[obj] = (1 - alpha) * np.asarray(rgb, np.float64)[..., :3][obj] + alpha * colour
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def write_label_previews(capture: Capture, n_materials: int | str, out: Path) -> dict:
    """The material labels Reconstruct would cluster (``cluster_labels`` on the frames' object
    pixels; ``n_materials`` a count or "auto", :func:`choose_material_count`) as colour
    overlays, one PNG per frame named as the frame, in ``out`` (replaced whole, atomically).
    The capture's own material masks, when it has them, are shown instead. Raises InputError
    when a frame has no object mask."""
    missing = [f for f in capture.frames if f.mask is None]
    require(not missing, missing[0].image if missing else None, "this frame has no object mask: the labels "
            "are clustered on object pixels", "import or make the object masks first (Solve Cameras)")
    images = [read_linear_rgb(f.image) for f in capture.frames]
    masks = [read_mask(f.mask) for f in capture.frames]
    labels = load_material_labels(capture)
    source = "material masks" if labels is not None else "colour clusters"
    if labels is None:
        k = choose_material_count(images, masks) if n_materials == "auto" else int(n_materials)
        labels = cluster_labels(images, masks, max(1, k))
    k = len(set(np.unique(np.concatenate([np.unique(li) for li in labels]))) - {0})
    with atomic_dir(out, replace=True) as tmp:
        for f, img, lab in zip(capture.frames, images, labels):
            rgb = np.round(255 * np.clip(linear_to_srgb(np.clip(img[..., :3], 0, 1)), 0, 1)).astype(np.uint8)
            Image.fromarray(label_overlay(rgb, lab)).save(tmp / f"{f.name}.png")
    shares = np.bincount(np.concatenate([li[li > 0].ravel() for li in labels]), minlength=k + 1)[1:]
    return {"materials": int(k), "frames": len(labels), "source": source, "folder": str(out),
            "shares": [round(float(s) / max(1, int(shares.sum())), 4) for s in shares]}
