"""AliceVision / openMVG projection export: ``P/<view>_P.txt`` (3x4 K[R|t] per view) and
``images/<view>.*``. Only views with both are used; the world frame is kept as it is."""

from __future__ import annotations

from pathlib import Path

from ...errors import require
from ..images import image_size
from ..model import Capture, Frame
from .common import image_files, numbers, projection_camera, read_text


def find(path: Path) -> Path | None:
    """The capture folder (holding ``P/`` and ``images/``) that ``path`` is or lies in."""
    folder = path.parent if path.is_file() else path
    for candidate in (folder, folder.parent):
        if (candidate / "P").is_dir() and (candidate / "images").is_dir() and any((candidate / "P").glob("*_P.txt")):
            return candidate
    return None


def load(path: Path, workdir: Path | None = None) -> Capture:
    root = find(path)
    frames = []
    for image in image_files(root / "images"):
        view = image.name.split(".")[0]
        p_file = root / "P" / f"{view}_P.txt"
        if not p_file.is_file():
            continue
        values = numbers(read_text(p_file).split(), p_file, f"view {view}")
        require(values.size == 12, p_file, f"{values.size} numbers instead of 12", "write a 3x4 projection matrix")
        w, h = image_size(image)
        frames.append(Frame(name=view, image=image,
                            camera=projection_camera(values.reshape(3, 4), w, h, p_file, f"view {view}")))
    require(len(frames) > 0, root / "images", "no image has a projection matrix in P/",
            "name images <view>.* to match P/<view>_P.txt")
    return Capture(root=root, frames=frames, provenance={"source": "alicevision", "path": str(root)})
