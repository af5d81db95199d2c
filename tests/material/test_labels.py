"""Material masks: bad input is refused naming the frame; per-face labels by majority vote."""

import numpy as np
import pytest
from PIL import Image

from backend import variant

variant.choose()

import mitsuba as mi  # noqa: E402

from backend.capture.images import write_image, write_mask  # noqa: E402
from backend.capture.model import Capture, Frame  # noqa: E402
from backend.errors import InputError  # noqa: E402
from backend.material import labels as L  # noqa: E402
from backend.render.scene import mitsuba_mesh  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

RES = 24


def capture_with_masks(tmp_path, material_masks, object_masks=None, size=(RES, RES)):
    """A capture of len(material_masks) frames; a None entry means that frame has no material mask."""
    frames = []
    cams = layout.orbit_cameras(layout.fibonacci_sphere(len(material_masks)), np.zeros(3), 1.0, size[0])
    for i, labels in enumerate(material_masks):
        image = tmp_path / f"images/{i:04d}.png"
        write_image(image, np.full((size[1], size[0], 3), 0.5, np.float32))
        mask = None
        if object_masks is not None:
            mask = tmp_path / f"masks/{i:04d}.png"
            write_mask(mask, object_masks[i])
        mat = None
        if labels is not None:
            mat = tmp_path / f"materials/{i:04d}.png"
            mat.parent.mkdir(exist_ok=True)
            Image.fromarray(np.asarray(labels, np.uint8)).save(mat)
        frames.append(Frame(f"{i:04d}", image, cams[i], mask=mask, material_mask=mat))
    return Capture(tmp_path, frames)


def disc(size=RES):
    y, x = np.mgrid[:size, :size]
    return (((x - size / 2) ** 2 + (y - size / 2) ** 2) < (size / 3) ** 2).astype(np.float32)


def two_materials(obj):
    lab = np.where(obj > 0, 1, 0)
    lab[: RES // 2][obj[: RES // 2] > 0] = 2
    return lab


def test_good_material_masks_are_read(tmp_path):
    obj = disc()
    cap = capture_with_masks(tmp_path, [two_materials(obj)] * 3, [obj] * 3)
    out = L.load_material_labels(cap)
    assert len(out) == 3 and set(np.unique(out[0])) == {0, 1, 2}


def test_missing_material_mask_names_the_frame(tmp_path):
    obj = disc()
    cap = capture_with_masks(tmp_path, [two_materials(obj), None, two_materials(obj)], [obj] * 3)
    with pytest.raises(InputError, match="frame 0001 has no material_mask"):
        L.load_material_labels(cap)


def test_wrong_size_material_mask_names_the_frame(tmp_path):
    obj = disc()
    small = two_materials(obj)[:20, :22]
    cap = capture_with_masks(tmp_path, [two_materials(obj), two_materials(obj), small], [obj] * 3)
    with pytest.raises(InputError, match="frame 0002: material mask is 22x20 but the frame is 24x24") as err:
        L.load_material_labels(cap)
    assert "materials/0002.png" in err.value.line()


def test_unassigned_object_pixels_are_refused(tmp_path):
    obj = disc()
    holes = two_materials(obj)
    holes[12, 12] = 0
    cap = capture_with_masks(tmp_path, [two_materials(obj), holes], [obj] * 2)
    with pytest.raises(InputError, match="frame 0001: 1 object pixels have no material label"):
        L.load_material_labels(cap)


def test_colour_label_image_is_refused(tmp_path):
    obj = disc()
    cap = capture_with_masks(tmp_path, [two_materials(obj)], [obj])
    rgb = np.zeros((RES, RES, 3), np.uint8)
    rgb[..., 0] = 1
    Image.fromarray(rgb).save(cap.frames[0].material_mask)
    with pytest.raises(InputError, match="colour image"):
        L.load_material_labels(cap)


def test_overlapping_binary_masks_and_count_mismatch_are_refused():
    obj = disc()
    a = obj.copy()
    b = np.zeros_like(obj)
    b[:5] = 1
    b[12, 12] = 1  # inside a too
    with pytest.raises(InputError, match="frame 0003: 1 pixels belong to more than one material mask"):
        L.combine_binary_masks("0003", [a, b])
    b[12, 12] = 0
    labels = L.combine_binary_masks("0003", [a, b])
    assert labels[12, 12] == 1 and labels[0, 0] == 2
    names = ["0000", "0001", "0002"]
    with pytest.raises(InputError, match="2 material masks for 3 frames"):
        L.check_label_set(names, [labels, labels], [(RES, RES)] * 3)


def pixel_labels(mesh, face_label, camera):
    """Ground-truth label image: the label of the face each pixel's centre ray hits (0 = miss)."""
    scene = mi.load_dict({"type": "scene", "m": mitsuba_mesh(mesh, mi.load_dict({"type": "diffuse"}))})
    v, u = np.mgrid[:camera.height, :camera.width] + 0.5
    d_cam = np.stack([(u - camera.cx) / camera.fx, -(v - camera.cy) / camera.fy, -np.ones_like(u)], -1)
    d = d_cam.reshape(-1, 3) @ camera.camera_to_world[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = camera.centre
    ray = mi.Ray3f(mi.Point3f(*[np.full(len(d), x, np.float32) for x in o]),
                   mi.Vector3f(*[d[:, i].astype(np.float32) for i in range(3)]))
    si = scene.ray_intersect(ray)
    hit = np.array(si.is_valid())
    prim = np.array(si.prim_index)
    out = np.zeros(len(d), np.int64)
    out[hit] = face_label[prim[hit]]
    return out.reshape(camera.height, camera.width)


def test_majority_vote_recovers_face_labels_and_reports_disagreement():
    mesh = procedural.blob(3)
    centroids = mesh.vertices[mesh.faces].mean(1)
    truth = np.where(centroids[:, 2] > 0.05, 7, 3)  # mask label values 3 and 7
    cams = layout.orbit_cameras(layout.fibonacci_sphere(12), np.zeros(3), 0.6, 64)
    images = [pixel_labels(mesh, truth, c) for c in cams]
    clean = L.vote_face_labels(mesh, cams, images)
    assert clean.material_ids == [3, 7]
    assert np.mean(np.array(clean.material_ids)[clean.labels] == truth) > 0.97
    # one view mislabels its left half: the vote still recovers the truth, and the share is reported
    wrong = images[0].copy()
    left = wrong[:, :32]
    wrong[:, :32] = np.where(left == 3, 7, np.where(left == 7, 3, 0))
    noisy = L.vote_face_labels(mesh, cams, [wrong] + images[1:])
    assert 0.0 < noisy.disagreement < 0.2
    assert clean.disagreement < noisy.disagreement
    assert np.mean(np.array(noisy.material_ids)[noisy.labels] == truth) > 0.95
    assert noisy.votes == clean.votes and noisy.unseen_faces == clean.unseen_faces < 0.05 * mesh.n_faces


def test_votes_read_label_images_larger_than_the_cameras():
    """The optimiser hands cameras scaled to its coarse size; the label images keep the
    capture's size: each camera is brought to its label image's size before indexing."""
    mesh = procedural.blob(3)
    centroids = mesh.vertices[mesh.faces].mean(1)
    truth = np.where(centroids[:, 0] > 0.0, 7, 3)
    full = layout.orbit_cameras(layout.fibonacci_sphere(12), np.zeros(3), 0.6, 64)
    images = [pixel_labels(mesh, truth, c) for c in full]
    coarse = [c.scaled(0.25) for c in full]
    votes = L.vote_face_labels(mesh, coarse, images)
    assert np.mean(np.array(votes.material_ids)[votes.labels] == truth) > 0.95


def test_clustering_separates_two_colours():
    rng = np.random.default_rng(0)
    obj = disc()
    truth = two_materials(obj)
    shade = rng.uniform(0.2, 1.0, obj.shape)[..., None]
    colour = np.where((truth == 2)[..., None], [0.1, 0.2, 0.7], [0.7, 0.3, 0.1]) * shade
    labels = L.cluster_labels([colour, colour[::-1]], [obj, obj[::-1]], k=2)
    for lab, t in zip(labels, [truth, truth[::-1]]):
        assert np.all(lab[t == 0] == 0)
        assert set(np.unique(lab[t > 0])) == {1, 2}
        same = lab[t > 0] == t[t > 0]
        assert same.all() or (~same).all()  # one cluster per colour (numbering is free)


def test_face_labels_from_clustered_frames():
    mesh = procedural.blob(3)
    centroids = mesh.vertices[mesh.faces].mean(1)
    truth = np.where(centroids[:, 2] > 0.05, 2, 1)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(8), np.zeros(3), 0.6, 48)
    rng = np.random.default_rng(0)
    images, masks = [], []
    for c in cams:
        lab = pixel_labels(mesh, truth, c)
        shade = rng.uniform(0.3, 1.0, lab.shape)[..., None]
        images.append(np.where((lab == 2)[..., None], [0.7, 0.2, 0.1], [0.1, 0.3, 0.6]) * shade * (lab > 0)[..., None])
        masks.append((lab > 0).astype(np.float32))
    result = L.face_labels(mesh, cams, None, images, masks, n_materials=2)
    assert result.n_materials == 2
    agree = np.mean(result.labels == (truth - 1))
    assert max(agree, 1 - agree) > 0.97  # cluster numbering is free
    single = L.face_labels(mesh, cams)
    assert single.n_materials == 1 and not single.labels.any()
