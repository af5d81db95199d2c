"""COLMAP sparse models (text or binary): cameras, registered images and 3D points.

COLMAP stores world-to-camera poses (quaternion, translation) with OpenCV camera axes and
principal points in the corner-based pixel convention we use. Its world has no defined
up, so it is kept as it is (scene levelling happens in the SfM stage). ``points3D`` is
written as ``points.ply`` into the work folder when one is given."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ... import fsio, ply
from ...errors import InputError, require
from ..format import check_pose
from ..images import srgb_to_linear
from ..model import Capture, Frame
from .common import opencv_camera, read_text

# model id -> (name, parameter names); unsupported models only need their parameter count.
MODELS = {
    0: ("SIMPLE_PINHOLE", ("f", "cx", "cy")),
    1: ("PINHOLE", ("fx", "fy", "cx", "cy")),
    2: ("SIMPLE_RADIAL", ("f", "cx", "cy", "k1")),
    3: ("RADIAL", ("f", "cx", "cy", "k1", "k2")),
    4: ("OPENCV", ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")),
    5: ("OPENCV_FISHEYE", (None,) * 8), 6: ("FULL_OPENCV", (None,) * 12), 7: ("FOV", (None,) * 5),
    8: ("SIMPLE_RADIAL_FISHEYE", (None,) * 4), 9: ("RADIAL_FISHEYE", (None,) * 5),
    10: ("THIN_PRISM_FISHEYE", (None,) * 12),
}
PARAMS = dict(MODELS.values())
MODEL_IDS = {name: i for i, (name, _) in MODELS.items()}
SUPPORTED = "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL or OPENCV"


def _has_model(folder: Path) -> bool:
    return any((folder / f"cameras{e}").is_file() and (folder / f"images{e}").is_file() for e in (".bin", ".txt"))


def find(path: Path) -> Path | None:
    """The model folder that ``path`` is, holds (``sparse/0``, ``sparse``) or a file of."""
    folder = path.parent if path.is_file() else path
    return next((d for d in (folder, folder / "sparse" / "0", folder / "sparse") if _has_model(d)), None)


def qvec_to_rotation(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / max(np.linalg.norm(q), 1e-300)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (z * x + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (z * x - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


# --- readers: cameras {id: (model name, width, height, params)}, images {id: (name, qvec, tvec,
# camera id)}, points (xyz (N, 3), rgb uint8 (N, 3)) ---

def _lines(path: Path):
    for line in read_text(path).splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            yield line.split()


def _read_cameras_txt(path: Path) -> dict:
    return {int(p[0]): (p[1], int(p[2]), int(p[3]), np.array(p[4:], dtype=np.float64)) for p in _lines(path)}


def _read_images_txt(path: Path) -> dict:
    images, lines = {}, read_text(path).splitlines()
    i = 0
    while i < len(lines):
        line = lines[i].strip()
        i += 1
        if not line or line.startswith("#"):
            continue
        p = line.split(maxsplit=9)
        images[int(p[0])] = (p[9], np.array(p[1:5], float), np.array(p[5:8], float), int(p[8]))
        i += 1  # the POINTS2D line that follows (possibly empty)
    return images


def _read_points_txt(path: Path):
    rows = list(_lines(path))
    xyz = np.array([r[1:4] for r in rows], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([r[4:7] for r in rows], dtype=np.uint8).reshape(-1, 3)
    return xyz, rgb


class _Reader:
    def __init__(self, path: Path):
        self.data, self.pos = path.read_bytes(), 0

    def read(self, fmt: str):
        values = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += struct.calcsize("<" + fmt)
        return values

    def skip(self, n: int):
        self.pos += n

    def string(self) -> str:
        end = self.data.index(b"\0", self.pos)
        s = self.data[self.pos:end].decode()
        self.pos = end + 1
        return s


def _read_cameras_bin(path: Path) -> dict:
    r, cameras = _Reader(path), {}
    for _ in range(r.read("Q")[0]):
        cam_id, model_id, w, h = r.read("iiQQ")
        require(model_id in MODELS, path, f"unknown camera model id {model_id}", "re-export the model")
        name, params = MODELS[model_id]
        cameras[cam_id] = (name, w, h, np.array(r.read("d" * len(params))))
    return cameras


def _read_images_bin(path: Path) -> dict:
    r, images = _Reader(path), {}
    for _ in range(r.read("Q")[0]):
        image_id, *qt, cam_id = r.read("idddddddi")
        name = r.string()
        r.skip(24 * r.read("Q")[0])  # points2D: x, y (double), point3D id (int64)
        images[image_id] = (name, np.array(qt[:4]), np.array(qt[4:]), cam_id)
    return images


def _read_points_bin(path: Path):
    r = _Reader(path)
    n = r.read("Q")[0]
    xyz, rgb = np.zeros((n, 3)), np.zeros((n, 3), np.uint8)
    for i in range(n):
        values = r.read("QdddBBBd")
        xyz[i], rgb[i] = values[1:4], values[4:7]
        r.skip(8 * r.read("Q")[0])  # track: image id, point2D index (int32 each)
    return xyz, rgb


def read_model(folder: Path):
    """(cameras, images, points or None) of the model in ``folder`` (binary preferred)."""
    ext = ".bin" if (folder / "cameras.bin").is_file() else ".txt"
    readers = {".bin": (_read_cameras_bin, _read_images_bin, _read_points_bin),
               ".txt": (_read_cameras_txt, _read_images_txt, _read_points_txt)}[ext]
    out = []
    for stem, reader in zip(("cameras", "images", "points3D"), readers):
        path = folder / f"{stem}{ext}"
        if stem == "points3D" and not path.is_file():
            out.append(None)
            continue
        try:
            out.append(reader(path))
        except (ValueError, IndexError, KeyError, struct.error, UnicodeDecodeError) as err:
            raise InputError(path, f"malformed COLMAP {stem} file ({err.__class__.__name__})",
                             "re-export the model from COLMAP") from err
    return tuple(out)


def _images_folder(model: Path, images: Path | None) -> Path:
    if images is not None:
        require(Path(images).is_dir(), images, "images folder not found", "give the folder of the frames")
        return Path(images)
    candidates = (model.parent / "images", model.parent.parent / "images", model / "images")
    found = next((d for d in candidates if d.is_dir()), None)
    require(found is not None, model, "no images/ folder found next to the COLMAP model",
            "put the frames in images/ beside the model folder or pass --images")
    return found


def load(path: Path, workdir: Path | None = None, images: Path | None = None) -> Capture:
    model = find(path)
    cameras, registered, points = read_model(model)
    image_dir = _images_folder(model, images)
    cam_file = next(model / f"cameras{e}" for e in (".bin", ".txt") if (model / f"cameras{e}").is_file())
    frames = []
    for name, qvec, tvec, cam_id in sorted(registered.values(), key=lambda im: im[0]):
        where = f"image {name}"
        require(cam_id in cameras, cam_file, f"{where} uses camera {cam_id}, which is not listed",
                "re-export the model")
        model_name, w, h, params = cameras[cam_id]
        names = PARAMS.get(model_name)
        require(names is not None and None not in names and len(params) == len(names), cam_file,
                f"camera {cam_id}: model {model_name} is not supported", f"calibrate with {SUPPORTED}")
        v = dict(zip(names, params))
        fx, fy = v.get("fx", v.get("f")), v.get("fy", v.get("f"))
        K = np.array([[fx, 0, v["cx"]], [0, fy, v["cy"]], [0, 0, 1]])
        camera = opencv_camera(K, qvec_to_rotation(qvec), tvec, w, h, pixel_offset=0.0,
                               distortion={k: v[k] for k in ("k1", "k2", "p1", "p2") if k in v})
        check_pose(camera.camera_to_world, model, where)
        frames.append(Frame(name=Path(name).with_suffix("").as_posix().replace("/", "_"),
                            image=image_dir / name, camera=camera))
    require(len(frames) > 0, model, "the COLMAP model has no registered images", "re-run the reconstruction")
    capture = Capture(root=image_dir.parent, frames=frames, provenance={"source": "colmap", "path": str(model)})
    if workdir is not None and points is not None and len(points[0]):
        capture.points = write_points(Path(workdir) / "points.ply", *points)
    return capture


def write_points(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> Path:
    """Sparse points ``xyz`` (N, 3) with 8-bit sRGB colours ``rgb`` (N, 3) as a face-less PLY
    with linear colours (the layout :func:`backend.geometry.mesh.load_mesh` reads), atomically."""
    fsio.write_bytes(path, ply.ply_bytes(xyz, colors=srgb_to_linear(rgb / 255.0)))
    return path
