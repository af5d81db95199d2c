"""A known object and known cameras, with writers for the layouts the importers read.

Everything here is written independently of the importers (scipy's quaternions, plain
projection matrices), so a round trip through an importer checks its conventions."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation

from backend.capture.model import CV_TO_GL, Camera

WIDTH, HEIGHT = 64, 48


def icosphere(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
         [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11],
         [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = f
    for _ in range(subdivisions):
        cache, new_faces = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                p = verts[a] + verts[b]
                verts.append(p / np.linalg.norm(p))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new_faces += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = new_faces
    return np.array(verts), np.array(faces)


def blob() -> tuple[np.ndarray, np.ndarray]:
    """An asymmetric closed object about 1.6 units across (a stretched sphere with a horn)."""
    v, f = icosphere(2)
    v = v * [0.8, 0.5, 0.4]
    v[:, 0] += 1.2 * np.maximum(v[:, 0], 0) ** 2 * (v[:, 2] + 0.4)
    return v + [0.1, -0.05, 0.1], f


def look_at(eye, target=(0, 0, 0), up=(0, 0, 1)) -> np.ndarray:
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, np.cross(right, forward), -forward, eye
    return m


def sphere_cameras(n: int = 6, fx=70.0, fy=72.0, cx=30.3, cy=25.1, seed: int = 0) -> list[Camera]:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        az, el = 2 * np.pi * (i + rng.uniform(0, 0.5)) / n, np.radians(rng.uniform(-30, 60))
        eye = 4.0 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cams.append(Camera(WIDTH, HEIGHT, fx, fy, cx, cy, look_at(eye, rng.normal(0, 0.05, 3))))
    return cams


def rasterise(vertices: np.ndarray, faces: np.ndarray, camera: Camera) -> np.ndarray:
    """Silhouette (H x W bool) with pixel centres at (i + 0.5, j + 0.5), as our model defines."""
    uv, z = camera.project(vertices)
    assert np.all(z > 0), "object behind the camera"
    mask = np.zeros((camera.height, camera.width), bool)
    for a, b, c in uv[faces]:
        lo = np.maximum(np.floor(np.minimum(np.minimum(a, b), c)).astype(int), 0)
        hi = np.minimum(np.ceil(np.maximum(np.maximum(a, b), c)).astype(int), [camera.width, camera.height])
        if np.any(hi <= lo):
            continue
        px, py = np.meshgrid(np.arange(lo[0], hi[0]) + 0.5, np.arange(lo[1], hi[1]) + 0.5)
        edges = [(q1[0] - q0[0]) * (py - q0[1]) - (q1[1] - q0[1]) * (px - q0[0])
                 for q0, q1 in ((a, b), (b, c), (c, a))]
        inside = (np.all([e >= 0 for e in edges], 0)) | (np.all([e <= 0 for e in edges], 0))
        mask[lo[1]:hi[1], lo[0]:hi[0]] |= inside
    return mask


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def world_to_camera_cv(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV-axes world-to-camera (R, t)."""
    m = CV_TO_GL @ np.linalg.inv(camera.camera_to_world)
    return m[:3, :3], m[:3, 3]


def projection(camera: Camera) -> np.ndarray:
    """3x4 K[R|t] with OpenCV's integer pixel centres."""
    K = np.array([[camera.fx, 0, camera.cx - 0.5], [0, camera.fy, camera.cy - 0.5], [0, 0, 1]])
    R, t = world_to_camera_cv(camera)
    return K @ np.c_[R, t]


def save_png(path: Path, mask: np.ndarray, rgba: bool = False) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    grey = (mask * 255).astype(np.uint8)
    data = np.dstack([grey, grey, grey, grey] if rgba else [grey, grey, grey])
    Image.fromarray(data).save(path)
    return path


# --- writers, one per layout ---

def write_transforms(folder: Path, cams, masks, *, angle_only=False, rgba=False, mask_folder=False) -> Path:
    frames = []
    for i, (cam, m) in enumerate(zip(cams, masks)):
        save_png(folder / "images" / f"{i:03d}.png", m, rgba=rgba)
        if mask_folder:
            save_png(folder / "masks" / f"{i:03d}.png", m)
        frames.append({"file_path": f"images/{i:03d}", "transform_matrix": cam.camera_to_world.tolist()})
    doc = {"camera_angle_x": 2 * np.arctan(0.5 * cams[0].width / cams[0].fx)} if angle_only else \
        {"fl_x": cams[0].fx, "fl_y": cams[0].fy, "cx": cams[0].cx, "cy": cams[0].cy,
         "w": cams[0].width, "h": cams[0].height}
    path = folder / "transforms.json"
    path.write_text(json.dumps(dict(doc, frames=frames)))
    return path


def _colmap_rows(cams):
    for i, cam in enumerate(cams):
        R, t = world_to_camera_cv(cam)
        x, y, z, w = Rotation.from_matrix(R).as_quat()
        yield i + 1, (w, x, y, z), t, f"{i:03d}.png"


def write_colmap_text(model: Path, cams, points: np.ndarray) -> None:
    model.mkdir(parents=True, exist_ok=True)
    (model / "cameras.txt").write_text("# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n" + "".join(
        f"{i + 1} PINHOLE {c.width} {c.height} {c.fx!r} {c.fy!r} {c.cx!r} {c.cy!r}\n" for i, c in enumerate(cams)))
    lines = ["# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME", "# POINTS2D[] as (X, Y, POINT3D_ID)"]
    for image_id, q, t, name in _colmap_rows(cams):  # image 2 observes every point, the others none
        observed = " ".join(f"{10.5 + k} 20.5 {k + 1}" for k in range(len(points)))
        lines += [" ".join(map(repr, (image_id, *map(float, q), *map(float, t), image_id))) + f" {name}",
                  observed if image_id == 2 else ""]
    (model / "images.txt").write_text("\n".join(lines) + "\n")
    (model / "points3D.txt").write_text("".join(
        f"{k + 1} {x!r} {y!r} {z!r} 200 100 50 0.5 2 {k}\n" for k, (x, y, z) in enumerate(points)))


def write_colmap_binary(model: Path, cams, points: np.ndarray) -> None:
    model.mkdir(parents=True, exist_ok=True)
    data = struct.pack("<Q", len(cams)) + b"".join(
        struct.pack("<iiQQ4d", i + 1, 1, c.width, c.height, c.fx, c.fy, c.cx, c.cy) for i, c in enumerate(cams))
    (model / "cameras.bin").write_bytes(data)
    data = struct.pack("<Q", len(cams))
    for image_id, q, t, name in _colmap_rows(cams):
        data += struct.pack("<i7di", image_id, *q, *t, image_id) + name.encode() + b"\0"
        observed = range(len(points)) if image_id == 2 else []
        data += struct.pack("<Q", len(observed)) + b"".join(struct.pack("<ddq", 10.5 + k, 20.5, k + 1) for k in observed)
    (model / "images.bin").write_bytes(data)
    data = struct.pack("<Q", len(points)) + b"".join(
        struct.pack("<Q3d3BdQ", k + 1, *p, 200, 100, 50, 0.5, 1) + struct.pack("<ii", 2, k)
        for k, p in enumerate(points))
    (model / "points3D.bin").write_bytes(data)


def write_idr(folder: Path, cams, masks, extra_views: int = 2) -> np.ndarray:
    """IDR/NeuS layout; returns the scale matrix (normalised -> world)."""
    S = np.diag([2.5, 2.5, 2.5, 1.0])
    S[:3, 3] = [1.0, -2.0, 3.0]
    mats = {}
    for i, cam in enumerate(cams + cams[:extra_views]):  # the extra views have no image
        P = np.vstack([projection(cam), [0, 0, 0, 1]])
        mats[f"world_mat_{i}"] = -3.0 * P @ np.linalg.inv(S)  # projections are defined up to scale
        mats[f"scale_mat_{i}"] = S
    for i, m in enumerate(masks):
        save_png(folder / "image" / f"{i:06d}.png", m)
        save_png(folder / "mask" / f"{i:03d}.png", m)
    np.savez(folder / "cameras_sphere.npz", **mats)
    return S


def write_middlebury(folder: Path, cams, masks, world_from_source: np.ndarray) -> Path:
    rows = []
    for i, (cam, m) in enumerate(zip(cams, masks)):
        save_png(folder / f"obj{i:04d}.png", m)
        source = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy,
                        np.linalg.inv(world_from_source) @ cam.camera_to_world)
        R, t = world_to_camera_cv(source)
        K = np.array([[cam.fx, 0, cam.cx - 0.5], [0, cam.fy, cam.cy - 0.5], [0, 0, 1]])
        rows.append(" ".join([f"obj{i:04d}.png"] + [repr(float(v)) for v in (*K.ravel(), *R.ravel(), *t)]))
    path = folder / "obj_par.txt"
    path.write_text(f"{len(rows)}\n" + "\n".join(rows) + "\n")
    return path


def write_alicevision(folder: Path, cams, masks) -> None:
    for i, (cam, m) in enumerate(zip(cams, masks)):
        save_png(folder / "images" / f"{i + 1:05d}._c.png", m)
        (folder / "P").mkdir(exist_ok=True)
        np.savetxt(folder / "P" / f"{i + 1:05d}_P.txt", 7.0 * projection(cam))
    np.savetxt(folder / "P" / f"{len(cams) + 1:05d}_P.txt", projection(cams[0]))  # a view without image
