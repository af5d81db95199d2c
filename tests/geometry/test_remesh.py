"""Re-meshing by ray casting + screened Poisson, cut to the masks: interior sheets vanish and
the genus can change (a sphere becomes a torus)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.bench._scenes import torus  # noqa: E402
from backend.capture.load import load_capture  # noqa: E402
from backend.geometry.mesh import Mesh, load_mesh, save_mesh  # noqa: E402
from backend.geometry.remesh import remesh, visible_samples  # noqa: E402
from backend.geometry.topology import genus, inspect  # noqa: E402
from backend.optimize.views import ViewSet  # noqa: E402
from backend.synth.procedural import icosphere  # noqa: E402
from tests.helpers import run_cli  # noqa: E402


@pytest.fixture(scope="module")
def torus_capture(tmp_path_factory) -> Path:
    """A torus (major radius 1, minor 0.35) from 12 views at 32 px."""
    folder = tmp_path_factory.mktemp("torus")
    save_mesh(folder / "torus.ply", torus())
    out = folder / "capture"
    run_cli("synth", "--out", out, "--mesh", folder / "torus.ply", "--views", 12, "--resolution", 32, "--spp", 16,
            "--held-out", 0, "--albedo", "0.6,0.6,0.6", check=True)
    return out


def test_ray_cast_samples_see_front_faces_only():
    sphere = icosphere(3, 0.5)
    from backend.synth.layout import fibonacci_sphere, orbit_cameras

    cams = orbit_cameras(fibonacci_sphere(4), np.zeros(3), 0.5, 24)
    samples = visible_samples(sphere, cams, None)
    assert len(samples.points) > 100 and samples.back_faces == 0
    assert np.allclose(np.linalg.norm(samples.points, axis=1), 0.5, atol=0.01)
    assert np.all(np.einsum("ij,ij->i", samples.normals, samples.points) > 0)  # outward
    inverted = Mesh(sphere.vertices, sphere.faces[:, ::-1])
    flipped = visible_samples(inverted, cams, None)
    assert len(flipped.points) == 0 and flipped.back_faces > 100


def test_remesh_cuts_a_sphere_into_a_torus(torus_capture):
    """A genus-0 surface spanning the hole: its hits over the hole project outside the masks,
    and the rebuilt surface, cut to the hull, has the torus's genus."""
    views = ViewSet(load_capture(torus_capture), 32).views
    blob = icosphere(4)
    blob.vertices *= np.array([1.35, 1.35, 0.35])  # a flat lens covering the torus and its hole
    assert genus(blob) == 0
    mesh, samples = remesh(blob, [v.camera for v in views], [v.mask for v in views], target_faces=3000)
    assert samples.outside_masks > 0
    report = inspect(mesh)
    assert report.closed_manifold and report.genus == 1 and mesh.n_faces <= 3000


def test_reconstruction_changes_genus(torus_capture, tmp_path):
    run = tmp_path / "run"
    proc = run_cli("reconstruct", torus_capture, "--out", run, "--init", "sphere", "--max-size", 32,
                   "--coarse-size", 32, "--initial-faces", 600, "--material", "known:0.6,0.6,0.6:0.25:0.35",
                   "--max-levels", 2, "--level-iterations", 150, "--step", 0.3, "--effects", "specular", timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads((run / "report.json").read_text())
    assert report["init"]["genus"] == 0
    assert report["levels"][0]["remesh"]["applied"]
    result = load_mesh(run / "result.ply")
    assert genus(result) == 1 and report["result"]["genus"] == 1


def test_a_remesh_with_too_few_samples_keeps_the_surface(torus_capture, tmp_path):
    """A start too small to cover a pixel in most views, in the torus's hole (outside every
    mask), leaves fewer than 16 consistent ray-cast samples: the re-mesh is skipped with a
    warning and the run goes on with the previous surface."""
    small = icosphere(3)
    small.vertices *= 0.03
    save_mesh(tmp_path / "around.ply", small)
    run = tmp_path / "run"
    proc = run_cli("reconstruct", torus_capture, "--out", run, "--init", tmp_path / "around.ply", "--remesh", "always",
                   "--max-size", 24, "--coarse-size", 24, "--initial-faces", 600, "--max-levels", 2,
                   "--level-iterations", 3, "--material", "known:0.6,0.6,0.6:0.25:0.35", "--effects", "specular",
                   timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    warnings = [e["message"] for e in events if e["event"] == "warning"]
    assert any("re-meshing not applied: only" in w and "consistent surface samples" in w for w in warnings), warnings
    report = json.loads((run / "report.json").read_text())
    assert report["levels"][0]["remesh"]["applied"] is False and len(report["levels"]) == 2


def _silhouettes(mesh, cameras):
    """Each camera's mask of ``mesh`` (1 where a pixel's ray hits it)."""
    from backend.geometry.raycast import RayCaster, pixel_rays

    caster = RayCaster(mesh)
    return [caster.intersect(*pixel_rays(c)).hit.reshape(c.height, c.width).astype(np.float32) for c in cameras]


def _bumpy(subdivisions: int = 4) -> Mesh:
    """A genus-0 star-shaped blob with deep bumps: contours everywhere the hull cut can graze."""
    blob = icosphere(subdivisions)
    v = blob.vertices
    blob.vertices = v * (1 + 0.3 * np.sin(4 * v[:, :1]) * np.sin(4 * v[:, 1:2]) * np.cos(3 * v[:, 2:]))
    return blob


def test_a_remesh_keeps_a_genus_0_object_at_genus_0():
    """The surface itself, re-meshed against its own silhouettes (no mask has a hole): what a
    level would go on with (``rebuild``'s surface, or the current one when it refuses) has
    genus 0; a refusal names the handles the cut added."""
    from backend.geometry.poisson import SurfaceReconstructionError
    from backend.geometry.remesh import poisson_from_samples, rebuild
    from backend.synth.layout import fibonacci_sphere, orbit_cameras

    blob = _bumpy()
    assert genus(blob) == 0
    cameras = orbit_cameras(fibonacci_sphere(12), np.zeros(3), 1.3, 40)
    masks = _silhouettes(blob, cameras)
    samples = visible_samples(blob, cameras, masks)
    cut = poisson_from_samples(samples, blob, 4000, cameras=cameras, masks=masks)
    try:
        mesh, handles = rebuild(samples, blob, 4000, cameras, masks)
    except SurfaceReconstructionError as err:
        assert "handles" in str(err) and (genus(cut) or 0) > 0, err
        mesh = blob
    else:
        assert handles["genus_after"] == 0 and mesh.n_faces <= 4000
    assert genus(mesh) == 0


def test_added_handles_need_views_that_see_through_them():
    """A torus rebuilt from a sphere: supported where the masks show its hole, not where they
    show a sphere; a rebuilt surface with no more handles is always supported."""
    from backend.geometry.remesh import handles_supported, mask_holes
    from backend.synth.layout import fibonacci_sphere, orbit_cameras

    ring, ball = torus(), icosphere(3, 1.35)
    cameras = orbit_cameras(fibonacci_sphere(8), np.zeros(3), 1.4, 32)
    ring_masks, ball_masks = _silhouettes(ring, cameras), _silhouettes(ball, cameras)
    assert sum(int(mask_holes(m).sum()) for m in ring_masks) > 20
    assert not any(mask_holes(m).any() for m in ball_masks)
    seen = handles_supported(ball, ring, cameras, ring_masks)
    assert seen["supported"] and (seen["genus_before"], seen["genus_after"]) == (0, 1)
    assert seen["see_through_after"] > seen["see_through_before"] + 20
    assert not handles_supported(ball, ring, cameras, ball_masks)["supported"]
    assert not handles_supported(ball, ring, cameras, None)["supported"]
    assert handles_supported(ring, ball, cameras, ball_masks)["supported"]
