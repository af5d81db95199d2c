"""The material stages a run reaches: a specular lobe once found stays on (a later highlight
measurement under the lighting and albedo fitted since is biased towards none), so a run
reaches the same stages whether or not views are held out."""

import json

from tests.helpers import run_cli

GLOSSY = ("--views", 8, "--resolution", 32, "--spp", 32, "--held-out", 0, "--specular", 0.4, "--roughness", 0.25,
          "--albedo", "0.5,0.4,0.3", "--lighting", "env", "--env", "sky")


def test_a_lobe_found_is_not_turned_off_by_a_later_measurement(tmp_path):
    """On a diffuse object the highlight test measures no lobe; after a decision that found
    one (as on DTU after a re-mesh), the same measurement keeps it on and says why."""
    from backend import variant

    variant.choose()
    from backend.capture.load import load_capture
    from backend.events import null_emitter
    from backend.geometry.mesh import load_mesh
    from backend.optimize.appearance import Appearance
    from backend.optimize.config import ReconstructConfig
    from backend.optimize.views import ViewSet
    from backend.render import effects

    out = tmp_path / "capture"
    run_cli("synth", "--out", out, "--views", 6, "--resolution", 32, "--spp", 32, "--specular", 0,
            "--albedo", "0.6,0.5,0.4", "--lighting", "env", "--env", "sky", "--held-out", 0, check=True)
    capture = load_capture(out)
    views = ViewSet(capture, 32).views
    mesh = load_mesh(capture.path(capture.ground_truth["mesh"]))
    fresh, found = (Appearance(capture, ReconstructConfig(material="staged", effects="auto"), null_emitter())
                    for _ in range(2))
    fresh.decide(mesh, fresh.initial_material(mesh, views), views, reason="initial mesh")
    assert not fresh.decision.specular, fresh.decision.reasons
    material = found.initial_material(mesh, views)
    found.decision = effects.EffectsDecision(specular=True)
    found.decide(mesh, material, views, reason="materials became spatially varying")
    ratio = found.decision.measured["highlight_ratio"]
    assert ratio <= effects.EffectsConfig().highlight_ratio, ratio
    assert found.decision.specular and "kept on" in found.decision.reasons["specular"]
    assert "specular" in material.trainable and found.history[-1]["enabled"]["specular"]


def test_held_out_views_do_not_change_the_stages_reached(tmp_path):
    """One glossy capture reconstructed with every view fitted and with every 4th view held out
    (--track-accuracy): both runs reach the same material stages, the specular one included."""
    run_cli("synth", "--out", tmp_path / "capture", *GLOSSY, check=True)
    settings = {"max_levels": 1, "polish_rounds": 0, "level_iterations": 15, "min_level_iterations": 5}
    fast = ["--max-size", "32", "--coarse-size", "32", "--initial-faces", "600", "--spp", "4"]
    reached = {}
    for name, extra in (("all", []), ("held", ["--track-accuracy", "--held-out-every", "4"])):
        proc = run_cli("reconstruct", tmp_path / "capture", "--out", tmp_path / name, *fast, *extra, timeout=600,
                       env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(settings)})
        assert proc.returncode == 0, proc.stderr[-3000:]
        report = json.loads((tmp_path / name / "report.json").read_text())
        reached[name] = {stage for stage, _ in report["material_schedule"]["schedule"]}
    assert len(report["accuracy_time"]["held_out_views"]) == 2
    assert reached["all"] == reached["held"] == {"constant", "diffuse", "specular"}, reached
