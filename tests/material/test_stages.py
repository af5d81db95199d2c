"""Material stages on a tiny synthetic scene: constants, textured diffuse with highlight masking,
textured specular with the variance penalty, the environment brightness factor, the schedule."""

import numpy as np
import pytest

from backend import variant

variant.choose()

from backend.capture.model import Environment  # noqa: E402
from backend.material import stages  # noqa: E402
from backend.material.schedule import MaterialSchedule, run_cycle  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402

RES = 32


def scene(env=False):
    mesh = procedural.blob(3)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(6), np.zeros(3), 0.6, RES)
    lights = [[] if env else layout.paper_lights(c, 2.0) for c in cams]
    truth = MeshColorMaterial(mesh, 1)
    truth.make_spatial("albedo")
    truth.set_values("albedo", procedural.albedo_pattern(truth.layout.sample_positions(mesh.vertices), 4.0))
    truth.set_values("specular", 0.4)
    truth.set_values("roughness", 0.3)
    return mesh, cams, lights, truth


def render_truth(mesh, cams, lights, truth, env=None, pixels=None):
    ref = SceneRenderer(mesh, truth.field, cams, lights, env, RenderSettings(spp=128, max_depth=3, integrator="path"),
                        env_pixels=pixels, rgba=True)
    out = [ref.render_numpy(v, seed=50 + v) for v in range(len(cams))]
    return [o[..., :3] for o in out], [o[..., 3] for o in out]


def albedo_rmse(material, truth):
    f = np.arange(material.n_faces)
    third = np.full(material.n_faces, 1 / 3)
    a = material.evaluate(f, third, third)["albedo"]
    b = truth.evaluate(f, third, third)["albedo"]
    return float(np.sqrt(np.mean((a - b) ** 2)))


def test_stages_reduce_loss_and_albedo_error():
    mesh, cams, lights, truth = scene()
    images, weights = render_truth(mesh, cams, lights, truth)
    material = MeshColorMaterial(mesh, 1)
    renderer = SceneRenderer(mesh, material.field, cams, lights, None,
                             RenderSettings(spp=8, max_depth=3, integrator="prb"))
    start = stages.evaluate_loss(renderer, images, weights, material)
    const = stages.fit_constants(renderer, images, weights, material, stages.FitSettings(iterations=30, lr=0.1))
    after_const = stages.evaluate_loss(renderer, images, weights, material)
    rmse_const = albedo_rmse(material, truth)
    assert after_const < 0.5 * start and const.losses[-1] < const.losses[0]
    assert material.values("specular")[0, 0] > 0.15  # the highlights need a specular lobe

    diffuse = stages.fit_diffuse(renderer, images, weights, material, stages.FitSettings(iterations=60, lr=0.1))
    assert 0.0 < diffuse.highlight_share < 0.25
    assert material.channels["albedo"].kind == "colors"
    rmse_diffuse = albedo_rmse(material, truth)
    assert rmse_diffuse < 0.7 * rmse_const
    after_diffuse = stages.evaluate_loss(renderer, images, weights, material)
    assert after_diffuse < after_const

    spec = stages.fit_specular(renderer, images, weights, material,
                               stages.FitSettings(iterations=30, lr=0.05, variance_weight=1.0))
    assert material.channels["specular"].kind == "colors" and spec.losses
    assert np.std(material.values("specular")) < 0.1  # the penalty keeps the specular smooth
    assert stages.evaluate_loss(renderer, images, weights, material) < after_const


def test_highlight_masks_sit_on_the_highlights():
    mesh, cams, lights, truth = scene()
    images, weights = render_truth(mesh, cams, lights, truth)
    renderer = SceneRenderer(mesh, truth.field, cams, lights, None, RenderSettings(spp=32, max_depth=2))
    masks = stages.highlight_masks(renderer, images, weights, truth, threshold=0.3)
    for v, mask in enumerate(masks):
        assert mask.any() and not (mask & (weights[v] == 0)).any()
        lum = images[v].mean(-1)
        assert lum[mask].mean() > 1.5 * lum[(weights[v] > 0) & ~mask].mean()  # the bright parts


def test_environment_brightness_factor_is_recovered():
    mesh, cams, lights, truth = scene(env=True)
    sky = procedural.sky(64)
    env = Environment("sky.exr", 1.0, 0.0)
    images, weights = render_truth(mesh, cams, lights, truth, env, sky)
    dim = Environment("sky.exr", 0.5, 0.0)  # the capture's strength is off by a factor of 2
    material = MeshColorMaterial(mesh, 1)
    for name in ("albedo", "specular", "roughness"):
        material.set_values(name, truth.values(name), truth.channels[name].kind)
    renderer = SceneRenderer(mesh, material.field, cams, lights, dim, RenderSettings(spp=8, max_depth=3, integrator="prb"),
                             env_pixels=sky)
    result = stages.fit(renderer, images, weights, material, [], stages.FitSettings(iterations=60, light_lr=0.08),
                        light=True)
    assert result.light_factor == pytest.approx(2.0, rel=0.1)
    assert material.light_factor == result.light_factor
    assert float(renderer.params[stages.ENV_SCALE][0]) == pytest.approx(0.5 * result.light_factor, rel=1e-5)


def test_schedule_runs_constant_then_diffuse_then_specular():
    s = MaterialSchedule(constant_cycles=5, patience=1)
    seen = []
    losses = iter([10, 9, 8, 7, 6, 5, 4, 4, 3, 2.5, 2.5, 2.5])
    while s.stage != "done":
        seen.append(s.stage)
        s.report(next(losses))
    assert seen == ["constant"] * 5 + ["diffuse"] * 3 + ["specular"] * 3
    s.on_remesh()
    assert s.stage == "constant" and s.constant_cycles == s.restart_cycles


def test_schedule_leaves_converged_constants_early():
    # a short run without re-meshing: constants that stop improving hand over to the textures
    s = MaterialSchedule(constant_cycles=5, patience=1)
    seen = []
    for loss in [10, 8, 8, 6, 5, 5]:
        seen.append(s.stage)
        s.report(loss)
    assert seen == ["constant"] * 3 + ["diffuse"] * 3 and s.stage == "specular"


def test_finalise_reopens_the_textures_once_with_more_patience():
    s = MaterialSchedule(constant_cycles=1, patience=1)
    for loss in [10, 9, 9, 8, 8]:
        s.report(loss)
    assert s.stage == "done"
    s.finalise()
    seen = []
    for loss in [7, 6.9, 6.5, 6.5, 6.5]:
        seen.append(s.stage)
        s.report(loss)
    # the finished textures go on in the specular stage (it fits every channel), until two
    # cycles bring no 1 % gain
    assert seen == ["specular"] * 5 and s.stage == "done"
    s.finalise()
    assert s.stage == "done"  # only once


def test_finalise_runs_diffuse_first_when_the_textures_had_not_got_that_far():
    unfinished = MaterialSchedule(constant_cycles=1, patience=1)
    unfinished.report(10)
    assert unfinished.stage == "diffuse"
    diffuse_only = MaterialSchedule(constant_cycles=1, patience=1, stage="done")
    for s, last in ((unfinished, "specular"), (diffuse_only, "diffuse")):
        s.finalise(last=last)
        seen = []
        for loss in [7, 6.9, 6.9, 6.9]:
            seen.append(s.stage)
            s.report(loss)
        assert seen == ["diffuse"] * 4 and s.stage == "specular"


def test_a_refinement_runs_one_cycle_of_the_last_stage():
    s = MaterialSchedule(constant_cycles=1, patience=1, stage="done")
    s.refine("specular")
    s.report(5.0)  # an improving cycle: the refinement still ends
    assert s.stage == "done" and s.cycle_limit is None
    s.refine("specular", cycles=2)
    s.report(4.0)
    assert s.stage == "specular"
    s.report(3.0)
    assert s.stage == "done"


def test_an_undone_cycle_ends_its_stage_even_with_patience_left():
    s = MaterialSchedule(constant_cycles=1, patience=1)
    for loss in [10, 9, 9, 8, 8]:
        s.report(loss)
    s.finalise(last="diffuse")  # patience 2, best reset
    s.report(7.0, reverted=True)  # the first final diffuse cycle is undone: no second try
    assert s.stage == "specular"
    s.report(6.0)
    s.report(5.0)
    assert s.stage == "specular"
    s.report(5.0, reverted=True)
    assert s.stage == "done"


def test_run_cycle_walks_the_schedule():
    mesh, cams, lights, truth = scene(env=True)
    sky = procedural.sky(64)
    env = Environment("sky.exr", 1.0, 0.0)
    images, weights = render_truth(mesh, cams[:3], lights[:3], truth, env, sky)
    material = MeshColorMaterial(mesh, 1)
    renderer = SceneRenderer(mesh, material.field, cams[:3], lights[:3], env,
                             RenderSettings(spp=4, max_depth=2, integrator="prb"), env_pixels=sky)
    schedule = MaterialSchedule(constant_cycles=1, patience=1, min_improvement=0.5)
    ran = []
    while schedule.stage != "done" and len(ran) < 8:
        ran.append(run_cycle(schedule, renderer, images, None, material,
                                    stages.FitSettings(iterations=4)).stage)
    assert ran[0] == "constant" and "diffuse" in ran and ran[-1] == "specular" and schedule.stage == "done"
    assert schedule.light_fitted and material.light_factor != 1.0
    assert material.channels["albedo"].kind == material.channels["specular"].kind == "colors"
    assert len(schedule.history) == len(ran)


def test_a_stage_that_raises_the_loss_is_undone():
    """A diverging fit (absurd steps on the truth itself) leaves the material as it was; a
    sound one is kept."""
    mesh, cams, lights, truth = scene()
    images, weights = render_truth(mesh, cams[:3], lights[:3], truth)
    renderer = SceneRenderer(mesh, truth.field, cams[:3], lights[:3], None,
                             RenderSettings(spp=8, max_depth=2, integrator="prb"))
    schedule = MaterialSchedule(constant_cycles=1)
    schedule.stage = "specular"
    before = {n: truth.values(n).copy() for n in truth.CHANNELS}
    loss = stages.evaluate_loss(renderer, images, weights, truth)
    result = run_cycle(schedule, renderer, images, weights, truth,
                              stages.FitSettings(iterations=6, lr=20.0, lr_decay=1.0))
    assert result.reverted and schedule.history[-1][1] == loss
    assert truth.channels["specular"].kind == "constant"  # the stage had made it mesh colors
    for n, values in before.items():
        np.testing.assert_allclose(truth.values(n), values, atol=1e-5)
    assert stages.evaluate_loss(renderer, images, weights, truth) == pytest.approx(loss, rel=1e-6)
    start = MeshColorMaterial(mesh, 1)  # neutral grey: a sound constant fit only improves it
    renderer = SceneRenderer(mesh, start.field, cams[:3], lights[:3], None,
                             RenderSettings(spp=8, max_depth=2, integrator="prb"))
    result = run_cycle(MaterialSchedule(), renderer, images, weights, start,
                              stages.FitSettings(iterations=10))
    assert not result.reverted and not np.allclose(start.values("albedo"), MeshColorMaterial(mesh, 1).values("albedo"))


def ring_scene(lobe):
    """16 views of the blob; ``lobe`` (sample heights -> specular) gives the truth's specular."""
    mesh = procedural.blob(3)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(16), np.zeros(3), 0.6, 24)
    lights = [layout.paper_lights(c, 2.0) for c in cams]
    truth = scene()[3]
    truth.make_spatial("specular")
    truth.set_values("specular", lobe(truth.layout.sample_positions(mesh.vertices)[:, 2]))
    images, weights = render_truth(mesh, cams, lights, truth)
    return mesh, cams, lights, truth, images, weights


def _renderer(mesh, material, cams, lights, spp=4):
    return SceneRenderer(mesh, material.field, cams, lights, None, RenderSettings(spp=spp, max_depth=2, integrator="prb"))


def test_specular_texture_is_kept_only_when_views_left_out_of_the_fit_show_it():
    mesh, cams, lights, truth, images, weights = ring_scene(lambda z: np.where(z > np.median(z), 0.8, 0.05))
    check = stages.check_views(len(cams), 8)
    assert check == [4, 12] and stages.check_views(15, 8) == [] and stages.check_views(16, 0) == []
    mean = float(truth.values("specular").mean())
    uniform = MeshColorMaterial(mesh, 1)
    for name in truth.CHANNELS:
        uniform.set_values(name, truth.values(name), truth.channels[name].kind)
    uniform.make_constant("specular")
    plain = render_truth(mesh, cams, lights, uniform)[0]
    # every view shows the textured lobe: the texture stays, value for value. Only the fitted
    # views show it (the others show its mean): it made up for something they do not repeat
    for targets, kept in ((images, "colors"), ([plain[v] if v in check else img for v, img in enumerate(images)],
                                               "constant")):
        material = MeshColorMaterial(mesh, 1)
        for name in truth.CHANNELS:
            material.set_values(name, truth.values(name), truth.channels[name].kind)
        result = stages.check_specular_texture(_renderer(mesh, material, cams, lights, spp=16), targets, weights,
                                               material, check)
        assert result["kept"] == kept and result["views"] == check
        assert material.channels["specular"].kind == kept
        if kept == "colors":
            assert result["colors"] < 0.8 * result["constant"]
            np.testing.assert_allclose(material.values("specular"), truth.values("specular"), atol=1e-5)
        else:
            assert result["constant"] < 0.8 * result["colors"]
            assert material.values("specular")[0, 0] == pytest.approx(mean, abs=0.05)


def test_the_specular_stage_is_fitted_without_its_check_views():
    mesh, cams, lights, truth, images, weights = ring_scene(lambda z: np.full_like(z, 0.4))
    check = stages.check_views(len(cams), 8)
    spoiled = [np.full_like(img, 5.0) if v in check else img for v, img in enumerate(images)]

    def fit_losses(targets, check_every):
        material = MeshColorMaterial(mesh, 1)
        schedule = MaterialSchedule()
        schedule.stage = "specular"
        result = run_cycle(schedule, _renderer(mesh, material, cams, lights), targets, weights, material,
                                  stages.FitSettings(iterations=16, check_every=check_every))
        assert material.channels["specular"].kind == "colors" or result.reverted
        return result.losses

    # the fit's own losses never see the check views: spoiling them changes nothing, unless
    # no views are left out (16 steps of one view each: every view is drawn once)
    np.testing.assert_allclose(fit_losses(spoiled, 8), fit_losses(images, 8), rtol=1e-4)
    assert sum(fit_losses(spoiled, 0)) > 5 * sum(fit_losses(images, 0))


def test_silhouette_band_is_left_out_of_the_fit():
    # pixels in the band just inside each outline do not steer the material: corrupting them
    # leaves the fit unchanged, while corrupting pixels further inside changes it
    mesh, cams, lights, truth = scene()
    cams, lights = cams[:2], lights[:2]
    images, weights = render_truth(mesh, cams, lights, truth)
    kept = stages.silhouette_weights(weights, 1)
    band = [(w > 0.5) & (k == 0) for w, k in zip(weights, kept)]
    assert all(b.any() for b in band) and all((k > 0).any() for k in kept)
    assert stages.silhouette_weights(weights, 0) is weights

    def constants(targets):
        material = MeshColorMaterial(mesh, 1)
        renderer = SceneRenderer(mesh, material.field, cams, lights, None, RenderSettings(spp=4, max_depth=2,
                                                                                          integrator="prb"))
        stages.fit_constants(renderer, targets, weights, material, stages.FitSettings(iterations=8, edge_erosion=1))
        return material.values("albedo")

    clean = constants(images)
    in_band = constants([np.where(b[..., None], 5.0, img) for b, img in zip(band, images)])
    inner = constants([np.where((k > 0)[..., None], 5.0 * img, img) for k, img in zip(kept, images)])
    np.testing.assert_allclose(in_band, clean, atol=1e-6)
    assert np.abs(inner - clean).max() > 0.01  # (8 small steps)


def test_robust_loss_is_squared_near_zero_and_linear_far_out():
    import drjit as dr
    import mitsuba as mi

    d = mi.Float([0.001, -0.001, 1.0, -2.0])
    np.testing.assert_allclose(np.array(stages.pixel_loss(d)), [1e-6, 1e-6, 1.0, 4.0], rtol=1e-6)
    c = 0.02
    robust = np.array(stages.pixel_loss(d, c))
    np.testing.assert_allclose(robust[:2], 1e-6, rtol=2e-3)  # ~ d^2 for |d| << c
    np.testing.assert_allclose(robust[2:], [2 * c * (1.0 - c), 2 * c * (2.0 - c)], rtol=1e-3)  # ~ 2 c |d|
    assert dr.width(stages.pixel_loss(d, c)) == 4


def test_robust_loss_resists_a_few_wrong_pixels():
    # a few pixels far off (as wrong geometry shades them) pull the squared-error fit away;
    # the robust fit stays closer to the fit on clean images
    mesh, cams, lights, truth = scene()
    cams, lights = cams[:2], lights[:2]
    images, weights = render_truth(mesh, cams, lights, truth)
    rng = np.random.default_rng(1)
    spoiled = [np.where((rng.random(w.shape) < 0.05)[..., None] & (w > 0)[..., None], 3.0, img)
               for img, w in zip(images, weights)]

    def constants(targets, robust):
        material = MeshColorMaterial(mesh, 1)
        renderer = SceneRenderer(mesh, material.field, cams, lights, None, RenderSettings(spp=4, max_depth=2,
                                                                                          integrator="prb"))
        stages.fit_constants(renderer, targets, weights, material,
                             stages.FitSettings(iterations=20, robust=robust, edge_erosion=0))
        return material.values("albedo")

    for robust in (0.0, 0.02):
        clean = constants(images, robust)
        if robust == 0.0:
            shift_l2 = np.abs(constants(spoiled, robust) - clean).max()
        else:
            shift_robust = np.abs(constants(spoiled, robust) - clean).max()
    assert shift_robust < 0.5 * shift_l2


def test_skip_to_starts_a_later_stage_and_never_goes_back():
    s = MaterialSchedule(constant_cycles=1, patience=2)
    s.report(10)
    s.report(9)
    assert s.stage == "diffuse" and s.cycle == 1
    s.skip_to("specular")
    assert (s.stage, s.cycle, s.stale) == ("specular", 0, 0)
    s.skip_to("diffuse")  # an earlier stage: ignored
    assert s.stage == "specular"
