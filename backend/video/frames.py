"""Frames from a video (PyAV) or a folder of images, picked by stride or count, blur rejected.

A *source* is either a video file or a folder of images (sorted by name, numbers in names
compared as numbers). Frame ``i`` of a source is the i-th frame in presentation order (or
the i-th file), so a mask source with the same number of frames pairs up by index.
Videos are turned upright by their display rotation (phones record it as metadata)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
from PIL import Image
from scipy import ndimage

from ..capture.images import read_mask
from ..capture.importers.common import IMAGE_SUFFIXES
from ..errors import InputError, require

SHARPNESS_SIZE = 640  # sharpness is measured on frames box-filtered down to about this size


def _natural_key(path: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


@dataclass
class Source:
    """Frames of a video file or an image folder: count, upright size, decoding by index."""

    path: Path
    count: int
    width: int
    height: int
    files: list[Path] | None = None  # image folder: one file per frame
    rotation: int = 0  # video: degrees counter-clockwise that turn decoded frames upright

    @property
    def is_video(self) -> bool:
        return self.files is None

    def frames(self, indices=None) -> Iterator[tuple[int, np.ndarray]]:
        """(index, HxWx3 uint8 RGB) for the wanted indices (all when None), in order."""
        wanted = None if indices is None else set(int(i) for i in indices)
        if self.files is not None:
            for i, path in enumerate(self.files):
                if wanted is None or i in wanted:
                    yield i, _read_rgb8(path)
            return
        last = max(wanted) if wanted else None
        for i, frame in enumerate(_decode(self.path)):
            if last is not None and i > last:
                return
            if wanted is None or i in wanted:
                yield i, _upright(frame.to_ndarray(format="rgb24"), self.rotation)


    def masks(self, indices=None) -> Iterator[tuple[int, np.ndarray]]:
        """(index, HxW float32 mask in [0, 1]): image files as ``read_mask`` reads them (alpha
        if present, else the mean of RGB), video frames as the mean of RGB."""
        if self.files is not None:
            wanted = None if indices is None else set(int(i) for i in indices)
            for i, path in enumerate(self.files):
                if wanted is None or i in wanted:
                    yield i, read_mask(path)
            return
        for i, rgb in self.frames(indices):
            yield i, rgb.mean(-1, dtype=np.float32) / 255.0


def _read_rgb8(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as im:
            if im.mode in ("I;16", "I;16B", "I"):
                return (np.asarray(im, np.float64)[..., None].repeat(3, -1) / 257).round().astype(np.uint8)
            return np.asarray(im.convert("RGB"))
    except Exception as err:
        raise InputError(path, f"cannot read image ({err.__class__.__name__})",
                         "replace the file with a valid PNG or JPEG") from err


def _upright(rgb: np.ndarray, rotation: int) -> np.ndarray:
    return np.ascontiguousarray(np.rot90(rgb, k=round(rotation / 90) % 4)) if rotation else rgb


def _decode(path: Path):
    import av  # here: only video decoding needs it

    try:
        with av.open(str(path)) as container:
            require(len(container.streams.video) > 0, path, "the file has no video stream",
                    "give a video file (MP4, MOV, MKV) or a folder of frames")
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            yield from container.decode(stream)
    except InputError:
        raise
    except Exception as err:  # PyAV raises many kinds (FFmpegError, ValueError, OSError)
        raise InputError(path, f"cannot decode the video ({err.__class__.__name__}: {err})".replace("\n", " "),
                         "re-export it as H.264 MP4 or give a folder of frames") from err


def _probe_video(path: Path) -> Source:
    import av  # here: only video decoding needs it

    first = next(_decode(path), None)
    require(first is not None, path, "the video has no frames", "give a video with frames")
    rotation = int(round(getattr(first, "rotation", 0) or 0))
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            count = sum(1 for packet in container.demux(stream) if packet.size > 0)
    except Exception as err:
        raise InputError(path, f"cannot read the video ({err.__class__.__name__})",
                         "re-export it as H.264 MP4 or give a folder of frames") from err
    w, h = first.width, first.height
    if round(rotation / 90) % 2:
        w, h = h, w
    return Source(path, count, w, h, rotation=rotation)


def _probe_folder(path: Path) -> Source:
    files = sorted((p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
                   key=_natural_key)
    require(len(files) > 0, path, "the folder holds no images", "give a folder of PNG or JPEG frames")
    sizes = {}
    for f in files:
        try:
            with Image.open(f) as im:
                sizes.setdefault(im.size, f)
        except Exception as err:
            raise InputError(f, f"cannot read image ({err.__class__.__name__})",
                             "replace the file with a valid PNG or JPEG") from err
    require(len(sizes) == 1, path, f"the images have different sizes ({', '.join(f'{w}x{h}' for w, h in sizes)})",
            "give frames of one size")
    (w, h), = sizes
    return Source(path, len(files), w, h, files=files)


def open_source(path: str | Path) -> Source:
    """A video file or an image folder, probed (frame count and size) without decoding it all."""
    path = Path(path)
    if not path.exists():
        raise InputError(path, "not found", "give a video file or a folder of frames")
    return _probe_folder(path) if path.is_dir() else _probe_video(path)


def check_masks(frames: Source, masks: Source) -> None:
    """Masks pair with frames by index: the same count and the same size."""
    require(masks.count == frames.count, masks.path,
            f"{masks.count} masks for {frames.count} frames of {frames.path.name}",
            "give one mask per source frame (the same number of images or video frames)")
    require((masks.width, masks.height) == (frames.width, frames.height), masks.path,
            f"masks are {masks.width}x{masks.height} but the frames are {frames.width}x{frames.height}",
            "export the masks at the frames' size")


def sharpness(rgb: np.ndarray) -> float:
    """Variance of the Laplacian of the grey frame, box-filtered to about SHARPNESS_SIZE px."""
    grey = np.asarray(rgb, np.float32)[..., :3].mean(-1) / 255.0
    k = max(1, max(grey.shape) // SHARPNESS_SIZE)
    if k > 1:
        h, w = grey.shape[0] // k * k, grey.shape[1] // k * k
        grey = grey[:h, :w].reshape(h // k, k, w // k, k).mean((1, 3))
    return float(ndimage.laplace(grey).var())


@dataclass
class Selection:
    indices: list[int]  # chosen source frame indices, increasing
    rejected: list[int]  # the sharpest frame of each bin that was still too blurred
    sharpness: np.ndarray  # per source frame


def select(sharp: np.ndarray, stride: int | None = None, count: int | None = None,
           blur_ratio: float = 0.5) -> Selection:
    """One frame per bin of ``stride`` frames (or ``count`` equal bins): the bin's sharpest,
    kept when its sharpness is at least ``blur_ratio`` times the median of its neighbourhood
    (about two bins either side), so a bin whose frames are all blurred gives no frame."""
    sharp = np.asarray(sharp, np.float64)
    n = len(sharp)
    if count is not None:
        edges = np.unique(np.round(np.linspace(0, n, min(count, n) + 1)).astype(int))
    else:
        edges = np.r_[np.arange(0, n, max(1, stride or 1)), n]
    width = max(1, int(np.ceil(n / max(1, len(edges) - 1))))
    reference = ndimage.median_filter(sharp, size=max(7, 4 * width + 1), mode="nearest")
    indices, rejected = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        best = int(a + np.argmax(sharp[a:b]))
        (indices if sharp[best] >= blur_ratio * reference[best] else rejected).append(best)
    return Selection(indices, rejected, sharp)


def pick_frames(source: Source, stride: int | None = None, count: int | None = None,
                blur_ratio: float = 0.5) -> Selection:
    """Measure every frame's sharpness (one decoding pass) and select."""
    sharp = np.array([sharpness(rgb) for _, rgb in source.frames()])
    require(len(sharp) > 0, source.path, "no frames could be decoded", "re-export the video")
    return select(sharp, stride, count, blur_ratio)
