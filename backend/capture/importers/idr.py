"""IDR / NeuS layout: ``cameras*.npz`` with ``world_mat_i`` (projection K[R|t]) and
``scale_mat_i`` (maps the unit sphere onto the object), images in ``image/``, masks in
``mask/``.

Cameras are produced in the normalised frame (object inside the unit sphere), from
P = world_mat @ scale_mat; the frame's up is whatever the dataset's is (DTU's is not
aligned with an axis, so it is kept). Files are matched to views by the number in their
stem (DTU: ``000004.png`` images, ``004.png`` masks); views without an image are skipped."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import InputError, require
from ..images import image_size
from ..model import Capture, Frame
from .common import image_files, projection_camera

PREFERRED = ("cameras_sphere.npz", "cameras.npz", "cameras_large.npz")


def find(path: Path) -> Path | None:
    """The cameras npz that ``path`` names or holds."""
    if path.is_file():
        return path if path.suffix == ".npz" else None
    if not path.is_dir():
        return None
    found = [path / n for n in PREFERRED if (path / n).is_file()] + sorted(path.glob("cameras*.npz"))
    return found[0] if found else None


def _numbered(folder: Path) -> dict[int, Path]:
    """Image files of ``folder`` by view index: the number in the stem, else the sorted order."""
    files = image_files(folder) if folder.is_dir() else []
    if all(f.stem.isdigit() for f in files):
        return {int(f.stem): f for f in files}
    return dict(enumerate(files))


def load(path: Path, workdir: Path | None = None) -> Capture:
    path = find(path)
    root = path.parent
    try:
        with np.load(path) as npz:
            mats = {k: np.asarray(npz[k], dtype=np.float64) for k in npz.files}
    except Exception as err:
        raise InputError(path, f"cannot read camera archive ({err.__class__.__name__})",
                         "re-export cameras.npz") from err
    image_dir = next((root / n for n in ("image", "images", "rgb") if (root / n).is_dir()), root / "image")
    images = _numbered(image_dir)
    require(len(images) > 0, image_dir, "no images found", "put the frames in image/ next to the npz")
    mask_dir = next((root / n for n in ("mask", "masks") if (root / n).is_dir()), None)
    masks = _numbered(mask_dir) if mask_dir else {}
    frames = []
    for i, image in sorted(images.items()):
        where = f"view {i}"
        require(f"world_mat_{i}" in mats, path, f"{where}: no world_mat_{i} for image {image.name}",
                "give a world_mat per image or remove the image")
        P = mats[f"world_mat_{i}"] @ mats.get(f"scale_mat_{i}", np.eye(4))
        w, h = image_size(image)
        mask = masks.get(i)
        require(mask_dir is None or mask is not None, mask_dir, f"no mask for {image.name}",
                "give one mask per image (or none at all)")
        frames.append(Frame(name=image.stem, image=image, camera=projection_camera(P, w, h, path, where),
                            mask=mask))
    return Capture(root=root, frames=frames, provenance={"source": "idr", "path": str(path)})
