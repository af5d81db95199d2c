"""The effects selector measures each effect and keeps only those a scene calls for."""

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.model import Camera, Environment, PointLight  # noqa: E402
from backend.geometry.mesh import Mesh  # noqa: E402
from backend.render import effects  # noqa: E402
from backend.render.fields import ConstantField, VertexField  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

RES = 48


def _decide(mesh, truth_field, cameras, lights, env=None, env_pixels=None):
    truth = SceneRenderer(mesh, truth_field, cameras, lights, env, RenderSettings(spp=64, max_depth=6),
                          env_pixels=env_pixels, rgba=True)
    targets = [truth.render_numpy(i) for i in range(len(cameras))]
    estimate = SceneRenderer(mesh, ConstantField([0.5, 0.5, 0.5], 0.2, 0.4), cameras, lights, env,
                             RenderSettings(spp=16), env_pixels=env_pixels)
    return effects.decide(estimate, [t[..., :3] for t in targets], [t[..., 3] for t in targets],
                          ["env" if env else "point"])


def _orbit(mesh, n=4):
    lo, hi = mesh.bounds()
    return layout.orbit_cameras(layout.fibonacci_sphere(n), (lo + hi) / 2, np.linalg.norm(hi - lo) / 2, RES)


def _quads(quads):
    verts, faces, colours = [], [], []
    for k, (p0, e1, e2, colour) in enumerate(quads):
        p0, e1, e2 = (np.asarray(a, float) for a in (p0, e1, e2))
        verts.append([p0, p0 + e1, p0 + e1 + e2, p0 + e2])
        faces.append(np.array([[0, 1, 2], [0, 2, 3]]) + 4 * k)
        colours += [colour] * 4
    return Mesh(np.vstack(verts), np.vstack(faces)), np.asarray(colours, np.float32)


def test_convex_diffuse_object_under_environment_needs_direct_light_only():
    sphere = procedural.icosphere(3)
    env = Environment("procedural", 1.0, 0.0)
    d = _decide(sphere, ConstantField([0.6, 0.5, 0.4], 0.0, 0.5), _orbit(sphere), [[]] * 4, env,
                procedural.sky(128))
    assert d.max_depth == 2 and not d.shadows and not d.specular, d.reasons
    assert d.measured["bounces"]["3"]["relative"] < 1e-3
    assert d.settings(RenderSettings(), geometry=False).integrator == "prb"
    assert d.settings(RenderSettings(), geometry=True).integrator == "direct_projective"


def test_glossy_object_keeps_the_specular_lobe():
    blob = procedural.blob(3)
    albedo = procedural.albedo_pattern(blob.vertices)
    n = len(albedo)
    field = VertexField(blob.faces, albedo, np.full(n, 0.4, np.float32), np.full(n, 0.25, np.float32))
    cams = _orbit(blob)
    d = _decide(blob, field, cams, [layout.paper_lights(c, 5.0) for c in cams])
    assert d.specular and d.measured["highlight_ratio"] > 1.5, d.reasons


@pytest.mark.parametrize("specular", [0.25, 0.0])
def test_specular_decision_on_a_rough_estimate(specular):
    """Measured on a sphere standing in for the blob (wrong normals, as a carved start has),
    the highlights of a glossy blob still count and a diffuse blob still has none: a wrong
    diffuse-only decision costs accuracy and saves no time."""
    blob = procedural.blob(3)
    lo, hi = blob.bounds()
    start = procedural.icosphere(3)
    start.vertices = (lo + hi) / 2 + start.vertices * 0.75 * np.linalg.norm(hi - lo) / 2
    cams = _orbit(blob)
    lights = [layout.paper_lights(c, 5.0) for c in cams]
    truth = SceneRenderer(blob, ConstantField([0.6, 0.6, 0.6], specular, 0.35), cams, lights,
                          settings=RenderSettings(spp=64, max_depth=4), rgba=True)
    targets = [truth.render_numpy(i) for i in range(len(cams))]
    estimate = SceneRenderer(start, ConstantField([0.5, 0.5, 0.5], 0.2, 0.4), cams, lights, settings=RenderSettings(spp=16))
    d = effects.decide(estimate, [t[..., :3] for t in targets], [t[..., 3] for t in targets], ["point"])
    assert d.specular == (specular > 0), d.reasons


def test_colour_bleeding_corner_keeps_multiple_bounces():
    corner, colours = _quads([([0, 0, 0], [1, 0, 0], [0, 1, 0], [0.8, 0.8, 0.8]),
                              ([0, 0, 0], [0, 1, 0], [0, 0, 1], [0.8, 0.1, 0.1]),
                              ([0, 0, 0], [0, 0, 1], [1, 0, 0], [0.1, 0.1, 0.8])])
    field = VertexField(corner.faces, colours, np.zeros(len(colours), np.float32), np.full(len(colours), 0.5, np.float32))
    cams = [Camera(RES, RES, 45.0, 45.0, RES / 2, RES / 2, layout.look_at(np.array([2.2, 2.2, 1.8]) + o, [0.3, 0.3, 0.3]))
            for o in ([0, 0, 0], [0.4, -0.3, 0], [-0.3, 0.4, 0.2])]
    lights = [[PointLight(np.array([1.5, 1.5, 2.0]), np.full(3, 4.0))]] * len(cams)
    d = _decide(corner, field, cams, lights)
    assert d.max_depth >= 3 and not d.specular, d.reasons
    assert d.measured["bounces"]["3"]["relative"] > 0.05


def _ball_on_floor():
    floor, _ = _quads([([-2, -2, 0], [4, 0, 0], [0, 4, 0], [0.7] * 3)])
    ball = procedural.icosphere(2, 0.5)
    ball.vertices[:, 2] += 0.5
    mesh = Mesh(np.vstack([floor.vertices, ball.vertices]), np.vstack([floor.faces, ball.faces + 4]))
    cams = [Camera(RES, RES, 40.0, 40.0, RES / 2, RES / 2, layout.look_at(e, [0, 0, 0.3]))
            for e in ([0, -4, 3], [3, -3, 3], [-3, -2, 3.5])]
    return mesh, cams


def test_object_on_a_floor_under_a_low_sun_needs_shadow_gradients():
    mesh, cams = _ball_on_floor()
    d = _decide(mesh, ConstantField([0.7, 0.7, 0.7], 0.0, 0.5), cams, [[]] * len(cams),
                Environment("procedural", 1.0, 0.0), procedural.sky(128, sun_elevation_deg=20.0))
    assert d.shadows and d.measured["self_shadowing"] > 0.05, d.reasons
    assert d.settings(RenderSettings(), geometry=True).sppi > 0


def test_point_lights_get_no_shadow_gradients():
    """The projective integrators sample no shadow boundaries of delta lights: under point
    lights the shadow term would cost without adding to the gradient, so it stays off."""
    mesh, cams = _ball_on_floor()
    lights = [[PointLight(np.array([3.0, 1.0, 1.2]), np.full(3, 15.0))]] * len(cams)
    d = _decide(mesh, ConstantField([0.7, 0.7, 0.7], 0.0, 0.5), cams, lights)
    assert not d.shadows and d.measured["self_shadowing"] is None and "point lights" in d.reasons["shadows"]
    assert d.settings(RenderSettings(), geometry=True).sppi == 0


@pytest.mark.parametrize("spec, measure, overrides", [
    ("auto", True, {}),
    ("all", False, {e: True for e in effects.EFFECTS}),
    ("auto,-shadows", True, {"shadows": False}),
    ("indirect,specular", False, {"indirect": True, "specular": True, "shadows": False, "silhouettes": True}),
    ("indirect,-silhouettes", False, {"indirect": True, "specular": False, "shadows": False, "silhouettes": False}),
])
def test_effects_option_parsing(spec, measure, overrides):
    assert effects.parse_effects(spec) == (measure, overrides)


def test_unknown_effect_is_rejected():
    with pytest.raises(ValueError, match="unknown effect"):
        effects.parse_effects("caustics")


def test_diffuse_only_decision_holds_through_the_material_schedule(tmp_path):
    """A diffuse object: the staged schedule fits no specular lobe (the constant stage's fit is
    zeroed, the specular stage is skipped after the re-check on entering it)."""
    from backend.capture.load import load_capture
    from backend.events import null_emitter
    from backend.geometry.mesh import load_mesh
    from backend.optimize.appearance import Appearance
    from backend.optimize.config import ReconstructConfig
    from backend.optimize.views import ViewSet
    from tests.helpers import run_cli

    out = tmp_path / "capture"
    run_cli("synth", "--out", out, "--views", 6, "--resolution", 32, "--spp", 32, "--specular", 0,
            "--albedo", "0.6,0.5,0.4", "--lighting", "env", "--env", "sky", "--held-out", 0, check=True)
    capture = load_capture(out)
    app = Appearance(capture, ReconstructConfig(material="staged", effects="auto"), null_emitter())
    app.driver.schedule.constant_cycles = 1
    app.driver.settings.iterations = 4
    views = ViewSet(capture, 32).views
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    material = app.initial_material(mesh, views)
    app.decide(mesh, material, views, reason="initial mesh")
    assert not app.decision.specular, app.decision.reasons
    stages = []
    for _ in range(8):
        result = app.material_cycle(mesh, material, views, level=0)
        if result is None:
            break
        stages.append(result["stage"])
        assert np.all(material.values("specular") < 1e-5) and "specular" not in material.trainable
    assert app.driver.done and "specular" not in stages and "diffuse" in stages, stages
    assert [h["reason"] for h in app.history] == ["initial mesh", "materials became spatially varying"]


def test_bench_targets_and_table():
    """The effects benchmark's verdict (its targets) and its all-scenes table."""
    from backend.bench import effects as bench

    ref = {"seconds": 400.0, "cpu_seconds": 380.0, "f1": 90.0, "albedo_rmse": 0.050, "psnr": 25.0, "steps": 60,
           "rc": 0, "decision": {"max_depth": 4, "shadows": True, "specular": True}}
    fast = dict(ref, seconds=100.0, cpu_seconds=90.0, f1=89.5, albedo_rmse=0.055, psnr=24.7,
                decision={"max_depth": 3, "shadows": False, "specular": False})
    assert [c["ok"] for c in bench.verdict("blob_env", ref, fast)] == [True, True, True]
    assert not bench.verdict("blob_env", ref, dict(fast, seconds=250.0))[0]["ok"]  # only 1.6x faster
    corner = bench.verdict("corner", ref, fast)
    assert [c["target"].split(" (")[0] for c in corner][:2] == ["keeps multi-bounce", "albedo RMSE matches"]
    assert all(c["ok"] for c in corner)
    direct = dict(fast, decision={"max_depth": 2}, albedo_rmse=0.08)
    assert [c["ok"] for c in bench.verdict("corner", ref, direct)] == [False, False, True, True]
    lossy = bench.verdict("dragon_cornell", ref, dict(fast, f1=88.5, psnr=24.0))
    assert [c["ok"] for c in lossy] == [False, False]
    results = {"scenes": {"corner": {"all": ref, "auto": fast, "auto,-shadows": fast},
                          "dragon_cornell": {"all": ref, "auto": {"rc": 1}}}}
    results["summary"] = {s: bench.summarise(s, r) for s, r in results["scenes"].items()}
    assert results["summary"]["corner"]["ok"] and results["summary"]["dragon_cornell"] is None
    text = bench.table(results)
    assert "4.0x" in text and "PASS" in text and "2 bounces" in text and "incomplete" in text


def _staged_appearance(tmp_path, *synth_args):
    from backend.capture.load import load_capture
    from backend.events import null_emitter
    from backend.geometry.mesh import load_mesh
    from backend.optimize.appearance import Appearance
    from backend.optimize.config import ReconstructConfig
    from backend.optimize.views import ViewSet
    from tests.helpers import run_cli

    out = tmp_path / "capture"
    run_cli("synth", "--out", out, "--views", 8, "--resolution", 32, "--spp", 32, "--held-out", 0, *synth_args,
            check=True)
    capture = load_capture(out)
    app = Appearance(capture, ReconstructConfig(material="staged", effects="auto"), null_emitter())
    app.driver.settings.iterations = 12
    views = ViewSet(capture, 32).views
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    return app, mesh, app.initial_material(mesh, views), views


def test_a_lobe_found_after_a_diffuse_only_decision_restarts_and_is_fitted(tmp_path):
    """A glossy object first judged diffuse (as on a carved start): when the re-check finds
    the highlights, the lobe restarts from neutral values (held at 0 its sigmoid has no slope)
    and its constants are fitted at once, lowering the full-view loss."""
    from backend.material import stages
    from backend.optimize.appearance import _disable_specular

    app, mesh, material, views = _staged_appearance(tmp_path)
    app.decision = effects.EffectsDecision(specular=False, max_depth=2)
    _disable_specular(material)
    app.specular_off = True
    app.driver.schedule.stage = "diffuse"  # the constants were fitted diffuse-only

    def full_loss():
        renderer = app._renderer(mesh, material, views, geometry=False)
        return stages.evaluate_loss(renderer, [v.target for v in views], app._masks(views), material)

    diffuse_only = full_loss()
    app.recheck(mesh, material, views, level=1)
    assert app.decision.specular, app.decision.reasons
    assert app.history[-1]["reason"].startswith("level 1")
    assert "specular" in material.trainable and app.driver.results[-1].stage == "lobe"
    assert float(material.values("specular").mean()) > 0.05, material.values("specular")
    assert full_loss() < 0.9 * diffuse_only


def test_simplification_keeps_a_diffuse_only_decision(tmp_path):
    """Simplifying carries the material over (resampled), the diffuse-only model with it, so
    geometry never trains under a lobe the effects ruled out."""
    from backend.geometry.simplify import simplify

    app, mesh, material, views = _staged_appearance(tmp_path, "--specular", 0, "--lighting", "env", "--env", "sky")
    app.decide(mesh, material, views, reason="initial mesh")
    assert not app.decision.specular, app.decision.reasons
    coarser = simplify(mesh, mesh.n_faces // 2)
    material.on_remesh(coarser, old_mesh=mesh, reset=False)
    assert np.all(material.values("specular") < 1e-5) and "specular" not in material.trainable
    app.recheck(coarser, material, views, level=1)  # still diffuse: measured again, stays off
    assert not app.decision.specular and np.all(material.values("specular") < 1e-5)


def test_term_share_separates_a_bias_from_noise():
    from backend.optimize.effect_costs import term_share

    rng = np.random.default_rng(0)
    g = rng.normal(size=(500, 3))
    term = 0.1 * rng.normal(size=(500, 3))  # an effect worth 10 % of the gradient
    base = [g + 0.05 * rng.normal(size=g.shape) for _ in range(3)]
    with_term = [b + term + 0.02 * rng.normal(size=g.shape) for b in base]
    share, noise, z = term_share(with_term, base)
    assert share == pytest.approx(np.linalg.norm(term) / np.linalg.norm(g + term), rel=0.1) and z > 5
    only_noise = [b + 0.1 * rng.normal(size=g.shape) for b in base]  # as large, but no bias
    share, noise, z = term_share(only_noise, base)
    assert z < 3 and noise > 0.05


@pytest.mark.parametrize("lighting", ["env", "points"])
def test_effects_weigh_cost_and_need_under_environment_light(tmp_path, lighting):
    """Under an environment map the decision times geometry steps with and without shadow
    gradients and one more bounce, measures each one's share of the gradient, and keeps it only
    when it pays; point-lit captures keep the need tests."""
    from backend.geometry.mesh import Mesh

    args = ["--lighting", "env", "--env", "sky"] if lighting == "env" else []
    app, mesh, material, views = _staged_appearance(tmp_path, *args)
    estimate = Mesh(mesh.vertices * 1.06, mesh.faces)  # off the truth: the gradient is not noise
    app.decide(estimate, material, views, reason="initial mesh")
    costs = app.decision.measured.get("costs")
    if lighting == "points":
        assert costs is None
        return
    assert set(costs) == {"shadows", "bounce"}, app.decision.reasons
    for name, cost in costs.items():
        assert cost["seconds"] > 0 and cost["base_seconds"] > 0 and cost["ratio"] > 0.5
        assert 0 <= cost["share"] < 2 and cost["noise"] >= 0 and np.isfinite(cost["z"])
    assert app.decision.shadows == costs["shadows"]["pays"]
    assert "x the step time" in app.decision.reasons["shadows"] and "bounce" in app.decision.reasons["indirect"]
    assert app.history[-1]["measured"]["costs"] == costs  # the effects event carries both


def test_the_cost_probe_runs_once_and_its_verdicts_hold_at_later_decisions(tmp_path):
    from backend.geometry.mesh import Mesh

    app, mesh, material, views = _staged_appearance(tmp_path, "--lighting", "env", "--env", "sky")
    estimate = Mesh(mesh.vertices * 1.06, mesh.faces)
    app.decide(estimate, material, views, reason="initial mesh")
    first = app.history[-1]
    app.decide(mesh, material, views, reason="re-meshed")
    later = app.history[-1]
    assert later["measured"]["costs"] == first["measured"]["costs"]
    assert later["measured"]["costs_measured_at"] == "initial mesh"
    assert later["enabled"]["shadows"] == first["measured"]["costs"]["shadows"]["pays"]
    assert later["seconds"] < first["seconds"]  # no steps timed the second time
