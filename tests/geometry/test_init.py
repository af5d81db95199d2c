"""Initialisations on small real captures: carving, sphere and box proxies, the sphere cloud,
a user mesh and SfM points + screened Poisson."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from backend.capture.format import save_capture
from backend.capture.load import load_capture
from backend.errors import InputError
from backend.geometry.init import default_kind, initial_mesh
from backend.geometry.init.carve import carve
from backend.geometry.init.hull import HullConfig, mask_views, sample
from backend.geometry.init.points_poisson import points_mesh
from backend.geometry.init.sphere import box_mesh, fit_sphere, sphere_mesh
from backend.geometry.init.spheres import sphere_cloud
from backend.geometry.mesh import Mesh, load_mesh, save_mesh
from backend.geometry.topology import inspect
from backend.metrics import geometry_metrics, sample_surface
from backend.synth.procedural import icosphere
from tests.helpers import run_cli


def volume(mesh: Mesh) -> float:
    v = mesh.vertices[mesh.faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6)


def closed(mesh: Mesh) -> bool:
    report = inspect(mesh)
    return report.closed_manifold and report.components == 1


@pytest.fixture(scope="module")
def six_views(tmp_path_factory) -> Path:
    """The built-in object seen by six cameras at 64 px (the fewest carving should handle)."""
    out = tmp_path_factory.mktemp("six") / "capture"
    run_cli("synth", "--out", out, "--views", 6, "--resolution", 64, "--spp", 16, "--held-out", 0, check=True)
    return out


@pytest.fixture(scope="module")
def sphere_views(tmp_path_factory) -> Path:
    """A sphere of radius 0.7 centred at (0.2, -0.1, 0.3), 10 views at 48 px."""
    folder = tmp_path_factory.mktemp("sphere")
    mesh = icosphere(4, 0.7)
    mesh.vertices += [0.2, -0.1, 0.3]
    save_mesh(folder / "sphere.ply", mesh)
    out = folder / "capture"
    run_cli("synth", "--out", out, "--mesh", folder / "sphere.ply", "--views", 10, "--resolution", 48, "--spp", 8,
            "--held-out", 0, check=True)
    return out


def test_carving_from_six_views_encloses_the_object(six_views):
    capture = load_capture(six_views)
    truth = load_mesh(six_views / "gt" / "mesh.ply")
    mesh = carve(capture, faces=3000)
    assert closed(mesh) and mesh.n_faces <= 3000
    assert volume(mesh) > volume(truth)  # a visual hull contains the object
    # points a pixel (0.02) under the object's surface are inside the hull field
    samples = sample_surface(truth, 2000)
    points = samples.points - 0.02 * truth.face_normals()[samples.faces]
    inside = sample(mask_views(capture), points, HullConfig())
    assert np.mean(inside > 0.5) > 0.97
    m = geometry_metrics(mesh, truth, samples=20000)
    assert m["chamfer_l1"] < 0.05  # within 5 % of the object's size with only six views


def test_sphere_fit_recovers_a_sphere(sphere_views):
    capture = load_capture(sphere_views)
    centre, radius = fit_sphere(capture)
    assert np.linalg.norm(centre - [0.2, -0.1, 0.3]) < 0.05 and radius == pytest.approx(0.7, rel=0.05)
    mesh = sphere_mesh(capture, faces=1500)
    assert closed(mesh) and inspect(mesh).genus == 0 and 320 <= mesh.n_faces <= 1500


def test_box_encloses_the_hull(six_views):
    capture = load_capture(six_views)
    box = box_mesh(capture, faces=1200)
    assert closed(box) and box.n_faces <= 1200
    truth = load_mesh(six_views / "gt" / "mesh.ply")
    lo, hi = box.bounds()
    assert np.all(truth.vertices >= lo - 1e-6) and np.all(truth.vertices <= hi + 1e-6)


def test_sphere_cloud_lies_inside_the_hull(six_views):
    capture = load_capture(six_views)
    cloud = sphere_cloud(capture, faces=3000)
    hull = carve(capture, faces=3000)
    assert closed(cloud) and cloud.n_faces <= 3000
    assert 0.4 * volume(hull) < volume(cloud) < 1.02 * volume(hull)


def test_user_mesh_is_checked(six_views, tmp_path):
    capture = load_capture(six_views)
    warnings = []
    good = tmp_path / "good.ply"
    save_mesh(good, icosphere(4, 0.4))
    mesh, kind = initial_mesh(capture, str(good), 1000, warnings.append)
    assert kind == str(good) and mesh.n_faces <= 1000 and closed(mesh) and not warnings
    holed = tmp_path / "holed.ply"
    sphere = icosphere(3, 0.4)
    save_mesh(holed, Mesh(sphere.vertices, sphere.faces[3:]))
    mesh, _ = initial_mesh(capture, str(holed), 5000, warnings.append)
    assert closed(mesh) and any("repaired" in w for w in warnings)
    with pytest.raises(InputError, match="neither"):
        initial_mesh(capture, str(tmp_path / "missing.ply"), 1000)


def test_points_and_poisson(six_views, tmp_path):
    capture = load_capture(six_views)
    truth = load_mesh(six_views / "gt" / "mesh.ply")
    with pytest.raises(InputError, match="point cloud"):
        points_mesh(capture)
    rng = np.random.default_rng(0)
    pts = sample_surface(truth, 3000, seed=1).points + rng.normal(scale=0.004, size=(3000, 3))
    outliers = rng.uniform(-3, 3, size=(30, 3))
    cloud = Mesh(np.vstack([pts, outliers]), np.zeros((0, 3), np.int64))
    save_mesh(six_views / "points.ply", cloud)
    capture.points = six_views / "points.ply"
    assert default_kind(capture) == "carve"  # masks win
    save_capture(capture)
    mesh = points_mesh(load_capture(six_views), faces=3000)
    assert closed(mesh) and mesh.n_faces <= 3000
    assert geometry_metrics(mesh, truth, samples=20000)["chamfer_l1"] < 0.02
    capture.frames = [f for f in capture.frames]
    for f in capture.frames:
        f.mask = None
    assert default_kind(capture) == "points"
