"""Camera refinement (backend/optimize/camera_fit.py): the closed-form chain rule, recovery of
perturbed cameras against a true mesh (real renders), and the run's switch and outputs."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from backend.bench.cameras import recovery
from backend.capture.load import load_capture
from backend.capture.model import Camera
from backend.geometry.mesh import Mesh
from backend.optimize import camera_fit as cf, camera_model as cm
from tests.helpers import run_cli

FAST = ["--max-size", "32", "--coarse-size", "16", "--initial-faces", "600", "--spp", "4", "--init", "sphere",
        "--effects", "specular", "--remesh", "never", "--material", "auto", "--max-levels", "2",
        "--level-iterations", "20"]


def _camera(rng) -> Camera:
    m = np.eye(4)
    m[:3, :3] = cm.rotation(rng.normal(size=3))
    m[:3, 3] = [0.3, -2.5, 0.4]
    return Camera(64, 48, 80.0, 80.0, 32.0, 24.0, m)


def test_the_chain_rule_matches_finite_differences_and_the_vertex_map_is_the_camera():
    rng = np.random.default_rng(1)
    cam = _camera(rng)
    pts, w = rng.normal(size=(40, 3)) * 0.4, rng.normal(size=(40, 3))
    focus = cam.camera_to_world[:3, :3].T @ (np.zeros(3) - cam.centre)

    def loss(om, phi, dolly, sigma, pp):
        m, b, _ = cm.vertex_map(cam, *cm.delta(om, phi, dolly, focus), sigma, pp)
        q = pts @ m.T + b
        return float((w * q).sum() + 0.5 * (q ** 2).sum())

    om, phi, dolly, sigma, pp = rng.normal(size=3) * 0.02, np.zeros(2), 0.01, 0.01, np.array([0.003, -0.002])
    rd, t = cm.delta(om, phi, dolly, focus)
    m, b, parts = cm.vertex_map(cam, rd, t, sigma, pp)
    q = pts @ m.T + b
    d_eps, d_t, d_sigma, d_a = cm.chain(w + q, pts, parts, sigma)
    g_om, g_phi, g_dolly = cm.pose_grads(d_eps, d_t, om, phi, dolly, focus)
    h = 1e-6
    turn = lambda e: cm.log_rotation(cm.rotation(om) @ cm.rotation(e))  # noqa: E731
    num_om = [(loss(turn(h * e), phi, dolly, sigma, pp) - loss(turn(-h * e), phi, dolly, sigma, pp)) / (2 * h)
              for e in np.eye(3)]
    num_phi = [(loss(om, h * e, dolly, sigma, pp) - loss(om, -h * e, dolly, sigma, pp)) / (2 * h) for e in np.eye(2)]
    num_dolly = (loss(om, phi, dolly + h, sigma, pp) - loss(om, phi, dolly - h, sigma, pp)) / (2 * h)
    num_sigma = (loss(om, phi, dolly, sigma + h, pp) - loss(om, phi, dolly, sigma - h, pp)) / (2 * h)
    num_a = [(loss(om, phi, dolly, sigma, pp + h * e) - loss(om, phi, dolly, sigma, pp - h * e)) / (2 * h)
             for e in np.eye(2)]
    np.testing.assert_allclose(g_om, num_om, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(g_phi, num_phi, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose([g_dolly, d_sigma], [num_dolly, num_sigma], rtol=1e-5)
    np.testing.assert_allclose(d_a, num_a, rtol=1e-5)
    # the moved vertices seen by the starting camera project where the corrected camera sees the mesh
    corrected = cm.corrected_camera(cam, rd, t, sigma, pp)
    np.testing.assert_allclose(corrected.project(pts)[0], cam.project(q)[0], atol=1e-8)


def test_auto_refines_solved_and_measured_cameras_not_rendered_ones():
    for source, expected in (("video", True), ("images", True), ("colmap", True), ("idr", True),
                             ("synth", False), ("nerf", False), (None, False)):
        capture = SimpleNamespace(provenance={"source": source} if source else {})
        assert cf.enabled("auto", capture) is expected, source
        assert cf.enabled("on", capture) and not cf.enabled("off", capture)
    rendered = SimpleNamespace(provenance={"source": "synth"})
    for mode in ("off", "auto"):  # a run that does not refine: nothing to restore, nothing written
        unrefined = cf.CameraRefinement.start(rendered, SimpleNamespace(refine_cameras=mode), None)
        assert isinstance(unrefined, cf.Unrefined) and unrefined.state() is None
        assert unrefined.finish(None, None, False) == {"refined": False, "mode": mode}


def test_auto_leaves_a_solve_finer_than_the_fit_can_see():
    frames = [SimpleNamespace(camera=SimpleNamespace(width=640, height=360))]
    solved = SimpleNamespace(provenance={"source": "video", "sfm": {"reprojection_error_px": 0.51}}, frames=frames)
    assert not cf.enabled("auto", solved, 256) and cf.enabled("on", solved, 256)
    assert "0.20 px at the fit's 256 px" in cf.unmeasurable(solved, 256)
    assert cf.enabled("auto", solved, 512) and cf.unmeasurable(solved, 512) is None  # 0.41 px there
    assert cf.enabled("auto", solved)  # no fit size given: by the source alone
    imported = SimpleNamespace(provenance={"source": "idr"}, frames=frames)  # no solve of its own
    assert cf.enabled("auto", imported, 128)
    unrefined = cf.CameraRefinement.start(solved, SimpleNamespace(refine_cameras="auto", max_size=256), None)
    report = unrefined.finish(None, None, False)
    assert report["refined"] is False and "reprojection error" in report["note"]


def test_a_non_finite_refined_camera_is_never_written(tmp_path):
    cam = _camera(np.random.default_rng(2))
    refinement = cf.CameraRefinement.__new__(cf.CameraRefinement)
    refinement.config = SimpleNamespace(refine_cameras="on")
    refinement.fit = cf.CameraFit(["a", "b"], [cam, cam], np.zeros(3))
    refinement.fit.refinements = 1
    refinement.fit.correction.omega[1] = np.nan
    with pytest.raises(ValueError):
        refinement.fit.cameras_json()
    report = refinement.finish(tmp_path, Mesh(np.random.default_rng(3).normal(size=(10, 3)), np.zeros((0, 3), int)),
                               held_out=False)
    assert report["diverged"] and not report["refined"]
    assert not (tmp_path / cf.FILENAME).exists()


def test_perturbed_cameras_are_recovered_against_the_true_mesh(tiny_capture):
    """Each camera turned by 1 degree and moved by 1 % of its distance; the true mesh and its
    material fixed. At 48 px the reprojection is recovered to a fraction of a pixel; pose
    errors drop too (the pan-orbit ambiguity of a 48-px view limits them: bench cameras has the
    full-size figure)."""
    out = recovery(tiny_capture, size=48, sweeps=8, rounds=2, intrinsics=False)
    before, after = out["before"], out["after"]
    assert after["reprojection_px"] < 0.35 * before["reprojection_px"], out
    assert after["rotation_deg"]["mean"] < 0.8 * before["rotation_deg"]["mean"], out
    assert after["translation_pct"]["mean"] < before["translation_pct"]["mean"], out


def _cameras(capture: Path) -> list[list]:
    return [f.camera.camera_to_world.tolist() for f in load_capture(capture).frames]


def test_reconstruct_refines_cameras_when_on_and_not_on_a_rendered_capture(tiny_capture, tmp_path):
    before = _cameras(tiny_capture)
    auto = run_cli("reconstruct", tiny_capture, "--out", tmp_path / "auto", *FAST, check=True)
    report = json.loads((tmp_path / "auto" / "report.json").read_text())
    assert report["cameras_refined"] == {"refined": False, "mode": "auto"}, auto.stdout[-2000:]
    assert not (tmp_path / "auto" / cf.FILENAME).exists()

    run_cli("reconstruct", tiny_capture, "--out", tmp_path / "on", *FAST, "--refine-cameras", "on", check=True)
    report = json.loads((tmp_path / "on" / "report.json").read_text())["cameras_refined"]
    assert report["refined"] and report["refinements"] >= 1 and not report["diverged"], report
    assert 0 <= report["reprojection_px"]["mean"] <= report["reprojection_px"]["max"] < 5.0
    written = json.loads((tmp_path / "on" / cf.FILENAME).read_text())
    assert written["format"] == cf.FORMAT and len(written["frames"]) == len(before)
    poses = np.array([f["camera"]["camera_to_world"] for f in written["frames"]])
    assert np.all(np.isfinite(poses))
    assert _cameras(tiny_capture) == before  # the capture itself is never rewritten
    events = [json.loads(line) for line in (tmp_path / "on" / "events.jsonl").read_text().splitlines()]
    assert any(e.get("event") == "cameras" for e in events)


def test_a_refinement_keeps_to_its_deadline_and_a_small_gain_settles_the_cameras(tiny_capture):
    """A deadline already past: one sweep, no Gauss-Newton frame, the loss still measured after.
    A refinement gaining less than ``SETTLED_GAIN`` settles the cameras: the next level does
    not refine again; a larger gain or a diverged one does not."""
    import time

    from backend.bench.cameras import FixedMaterial
    from backend.geometry.mesh import load_mesh
    from backend.optimize.views import ViewSet
    from backend.render.scene import RenderSettings

    capture = load_capture(tiny_capture)
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    viewset = ViewSet(capture, 32)
    config = SimpleNamespace(refine_cameras="on", camera_sweeps=4, camera_newton=2, seed=0, tone="log",
                             time_budget_s=None)
    refinement = cf.CameraRefinement(capture, config, viewset)
    settings = RenderSettings(spp=4, max_depth=2, integrator="direct_projective", sppc=4, sppp=4)
    record = refinement.fit.refine(mesh, FixedMaterial(mesh), viewset.at(32), settings, capture.environment,
                                   sweeps=4, newton=2, deadline=time.perf_counter())
    assert record["sweeps"] == 1 and record["newton_frames"] == 0 and record["seconds"] > 0, record
    assert np.isfinite(record["loss_end"]) and record["loss_end"] <= record["loss_start"] * cf.WORSE, record
    gain = (record["loss_start"] - record["loss_end"]) / record["loss_start"]
    assert refinement.settled() == (not record["diverged"] and gain < refinement.SETTLED_GAIN)
    refinement.fit.history[-1].update(loss_start=1.0, loss_end=0.999, diverged=False)  # a 0.1 % gain
    assert refinement.settled()
    state = SimpleNamespace(level=2)
    refinement.after_level(state, None, [], settings, None, None, None, None)  # returns before refining
    assert refinement.fit.refinements == 1
    refinement.fit.history[-1].update(loss_end=0.9)
    assert not refinement.settled()
    refinement.fit.history[-1].update(loss_end=1.0, diverged=True)
    assert not refinement.settled()
    assert refinement.deadline(SimpleNamespace(seconds_left=lambda: None)) is None  # no time budget: no deadline


def test_gauss_newton_steps_span_the_orbit_and_stop_where_they_gain_nothing(tiny_capture, monkeypatch):
    """The steps visit the frames interleaved, so any prefix spans the capture. After the probe
    frames, their net gain (the refinement's loss after their steps against its start) decides:
    on the exact cameras it is small and the rest are left (``gain``); on cameras turned by a
    degree it is large and every frame gets its steps. The bar here sits between the two (at
    this 32-px size the exact cameras still gain a little from the resampled targets)."""
    from backend.bench.cameras import FixedMaterial, perturb
    from backend.geometry.mesh import load_mesh
    from backend.optimize.views import ViewSet
    from backend.render.scene import RenderSettings

    order = cf.newton_order(20)
    assert sorted(order) == list(range(20)) and order[:3] == [0, 8, 16] and max(order[:4]) - min(order[:4]) >= 15
    monkeypatch.setattr(cf, "NEWTON_PROBE", 2)
    monkeypatch.setattr(cf, "NEWTON_GAIN", 0.1)
    settings = RenderSettings(spp=4, max_depth=2, integrator="direct_projective", sppc=4, sppp=4)
    records = {}
    for turned in (0.0, 1.0):
        capture = load_capture(tiny_capture)
        mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
        lo, hi = mesh.bounds()
        cams = perturb([f.camera for f in capture.frames], 0.5 * (lo + hi), turned, turned, seed=4)
        for frame, cam in zip(capture.frames, cams):
            frame.camera = cam
        fit = cf.CameraFit([f.name for f in capture.frames], cams, 0.5 * (lo + hi))
        records[turned] = fit.refine(mesh, FixedMaterial(mesh), ViewSet(capture, 32).at(32), settings,
                                     capture.environment, sweeps=0, newton=2, intrinsics=False)
    n = len(load_capture(tiny_capture).frames)
    exact, turned = records[0.0], records[1.0]
    assert exact["newton_stopped"] == "gain" and exact["newton_frames"] == 2, exact
    assert turned["newton_stopped"] is None and turned["newton_frames"] == n, turned
    assert exact["newton_gain"] < cf.NEWTON_GAIN < turned["newton_gain"], records
