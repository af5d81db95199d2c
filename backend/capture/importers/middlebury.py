"""Middlebury multi-view stereo: ``<name>_par.txt`` with one line per image,
``imgname k11..k33 r11..r33 t1 t2 t3``, projection K[R|t] in OpenCV axes.

The gantry turns about the source world's +Y axis and the objects stand along +Y (the
dino's base is at -Y), so the world is turned Y-up -> Z-up: (x, y, z) -> (x, -z, y); the
matrix is in ``provenance["world_from_source"]``. There are no mask files: masks are
derived with the dataset README's recipe (luma threshold 0.19, dilate 10 px, erode 7 px)
into ``workdir/masks`` when a work folder is given, else frames have no masks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from ...errors import require
from ..format import check_pose
from ..images import image_size, read_rgba, write_mask
from ..model import Capture, Frame
from .common import numbers, opencv_camera, read_text, transformed

Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
THRESHOLD, DILATE_PX, ERODE_PX = 0.19, 10, 7


def find(path: Path) -> Path | None:
    """The ``*_par.txt`` file that ``path`` names or holds."""
    if path.is_file():
        return path if path.name.endswith("_par.txt") else None
    found = sorted(path.glob("*_par.txt")) if path.is_dir() else []
    return found[0] if found else None


def _disk(radius: int) -> np.ndarray:
    y, x = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    return x * x + y * y <= radius * radius


def derive_mask(image: Path) -> np.ndarray:
    """The README's silhouette recipe on the image's stored (sRGB) values."""
    rgb = read_rgba(image)[0][..., :3]
    luma = rgb @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    mask = ndimage.binary_dilation(luma > THRESHOLD, _disk(DILATE_PX))
    return ndimage.binary_erosion(mask, _disk(ERODE_PX), border_value=1)


def load(path: Path, workdir: Path | None = None) -> Capture:
    path = find(path)
    root = path.parent
    rows = [line.split() for line in read_text(path).splitlines()[1:] if line.strip()]
    require(len(rows) > 0, path, "no camera lines", "one line per image: name k11..k33 r11..r33 t1 t2 t3")
    frames = []
    for row in rows:
        where = f"image {row[0]}"
        require(len(row) == 22, path, f"{where}: {len(row) - 1} numbers instead of 21",
                "write name k11..k33 r11..r33 t1 t2 t3")
        v = numbers(row[1:], path, where)
        image = root / row[0]
        w, h = image_size(image)
        camera = opencv_camera(v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:], w, h, pixel_offset=0.5)
        check_pose(camera.camera_to_world, path, where)
        frames.append(Frame(name=image.stem, image=image, camera=transformed(camera, Y_UP_TO_Z_UP)))
    good = root / path.name.replace("_par.txt", "_good_silhouette_images.txt")
    provenance = {"source": "middlebury", "path": str(path), "world_from_source": Y_UP_TO_Z_UP.tolist()}
    if good.is_file():
        provenance["good_silhouettes"] = [Path(n).stem for n in read_text(good).split()]
    if workdir is not None:
        for frame in frames:
            frame.mask = Path(workdir) / "masks" / f"{frame.name}.png"
            write_mask(frame.mask, derive_mask(frame.image).astype(np.float32))
    return Capture(root=root, frames=frames, provenance=provenance)
