"""The specular stage under a diffuse-only decision: the loss, not the image test, decides
whether the lobe stays, so a run reaches the same stages whether or not views are held out."""

import json

import numpy as np

from tests.helpers import run_cli

GLOSSY = ("--views", 12, "--resolution", 32, "--spp", 32, "--held-out", 0, "--specular", 0.4, "--roughness", 0.25,
          "--albedo", "0.5,0.4,0.3")


def _appearance(tmp_path):
    from backend.capture.load import load_capture
    from backend.events import null_emitter
    from backend.geometry.mesh import load_mesh
    from backend.optimize.appearance import Appearance
    from backend.optimize.config import ReconstructConfig
    from backend.optimize.views import ViewSet

    out = tmp_path / "capture"
    run_cli("synth", "--out", out, *GLOSSY, check=True)
    capture = load_capture(out)
    app = Appearance(capture, ReconstructConfig(material="staged", effects="auto"), null_emitter())
    app.driver.settings.iterations = 12
    views = ViewSet(capture, 32).views
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    return app, mesh, app.initial_material(mesh, views), views


def test_a_lobe_the_image_test_missed_is_kept_by_the_loss(tmp_path):
    """A glossy object judged diffuse-only when the schedule enters its specular stage (as under
    a fitted lighting that has taken up the highlights): the lobe's constants are fitted, they
    lower the full-view loss, so the lobe turns on and the specular stage runs."""
    from backend.material.driver import LOBE_GAIN
    from backend.optimize.appearance import _disable_specular
    from backend.render import effects

    app, mesh, material, views = _appearance(tmp_path)
    app.decision = effects.EffectsDecision(specular=False, max_depth=2)
    _disable_specular(material)
    app.specular_off = True
    app.driver.schedule.stage = "specular"
    before = app.full_loss(mesh, material, views)
    result = app.material_cycle(mesh, material, views, level=0)
    assert result is not None and result["stage"] == "specular", result
    trial = app.lobe_trials[-1]
    assert trial["kept"] and trial["gain"] >= LOBE_GAIN, trial
    assert app.decision.specular and "specular" in material.trainable
    assert app.history[-1]["reason"] == "specular stage: the lobe tried"
    assert float(material.values("specular").mean()) > 0.02
    assert app.full_loss(mesh, material, views) < (1 - LOBE_GAIN) * before


def _stages(run) -> list[str]:
    report = json.loads((run / "report.json").read_text())
    return [stage for stage, _ in report["material_schedule"]["schedule"]]


def test_held_out_views_do_not_change_the_stages_reached(tmp_path):
    """One glossy capture reconstructed with every view fitted and with every 4th view held out
    (--track-accuracy): both runs reach the same material stages, the specular one included."""
    run_cli("synth", "--out", tmp_path / "capture", *GLOSSY, "--lighting", "env", "--env", "sky", check=True)
    settings = {"max_levels": 1, "polish_rounds": 1, "level_iterations": 15, "min_level_iterations": 5}
    fast = ["--max-size", "32", "--coarse-size", "32", "--initial-faces", "600", "--spp", "4"]
    reached = {}
    for name, extra in (("all", []), ("held", ["--track-accuracy", "--held-out-every", "4"])):
        proc = run_cli("reconstruct", tmp_path / "capture", "--out", tmp_path / name, *fast, *extra, timeout=600,
                       env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(settings)})
        assert proc.returncode == 0, proc.stderr[-3000:]
        reached[name] = _stages(tmp_path / name)
    report = json.loads((tmp_path / "held" / "report.json").read_text())
    assert len(report["accuracy_time"]["held_out_views"]) == 3
    assert set(reached["all"]) == set(reached["held"]) == {"constant", "diffuse", "specular"}, reached
    assert np.isfinite([loss for _, loss in json.loads((tmp_path / "all" / "report.json").read_text())
                        ["material_schedule"]["schedule"]]).all()
