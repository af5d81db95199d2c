"""``--lighting rig``: an environment map fixed to each view's camera (lamps on the camera rig).

Real renders: a grey sphere under a rig map whose one bright patch sits toward the camera
looks the same from every camera (the light turns with the view), and brightest where it
faces the camera; under the same map fixed to the world it does not. End to end: on a capture
lit by a flash at each camera (no light recorded), a rig run's held-out views, rendered under
its map turned with each held-out camera, beat a world-fixed estimate's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from backend import variant

variant.choose()

from backend.capture.model import Environment  # noqa: E402
from backend.lighting import estimated_map  # noqa: E402
from backend.material.model import MeshColorMaterial  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402
from backend.synth import layout, procedural  # noqa: E402
from tests.helpers import run_cli  # noqa: E402
from tests.lighting.test_fitted import ESTIMATE_FAST, ESTIMATE_SETTINGS, evaluate, strip_light  # noqa: E402


def _rig_map(width: int = 32, height: int = 16) -> np.ndarray:
    """A dim map with one bright patch at the rig frame's +x (toward the camera), a little above."""
    d = estimated_map.directions(width, height)
    toward = np.array([np.cos(0.3), 0.0, np.sin(0.3)])
    lobe = np.exp(12 * (d @ toward - 1))[..., None]
    return (0.05 + 20 * lobe * np.ones(3)).astype(np.float32)


def _renders(frame: str) -> np.ndarray:
    mesh = procedural.icosphere(3)
    cams = layout.orbit_cameras(layout.fibonacci_sphere(4), np.zeros(3), 1.0, 32)
    material = MeshColorMaterial(mesh, 1)
    material.set_values("albedo", [0.5, 0.5, 0.5])
    material.disable("specular")
    env = Environment(Path("rig.exr"), 1.0, 0.0, "estimated", pixels=_rig_map(), frame=frame)
    r = SceneRenderer(mesh, material.field, cams, [[] for _ in cams], env,
                      RenderSettings(spp=64, max_depth=2, integrator="path"))
    return np.stack([r.render_numpy(v, seed=1) for v in range(len(cams))])


def test_a_rig_map_turns_with_the_camera():
    rig, world = _renders("camera"), _renders("world")
    lum = rig.mean(-1)
    # every view sees the same lit sphere: the light comes from its camera
    spread = np.abs(lum - lum.mean(0)).mean() / lum.mean()
    assert spread < 0.08, spread
    # lit from the camera, a little above: the centre brighter than the rim, the top than the bottom
    h = lum.shape[1]
    assert lum[:, h // 2 - 2:h // 2 + 2, h // 2 - 2:h // 2 + 2].mean() > 1.15 * lum[:, h // 2, 3:6].mean()
    assert lum[:, 4:10, 12:20].mean() > 1.3 * lum[:, 24:29, 12:20].mean()
    # fixed to the world instead, the views differ
    wl = world.mean(-1)
    assert np.abs(wl - wl.mean(0)).mean() / wl.mean() > 3 * spread


def test_rig_axes_are_the_cameras_back_right_and_up():
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], float)  # GL x -> world y, y -> z, z -> x
    axes = Environment.rig_axes(c2w)
    assert np.allclose(axes[:, 0], c2w[:3, 2]) and np.allclose(axes[:, 1], c2w[:3, 0])
    assert np.allclose(axes[:, 2], c2w[:3, 1]) and np.isclose(np.linalg.det(axes), 1)


def test_a_rig_run_follows_a_flash_that_a_world_map_cannot(tmp_path):
    capture = tmp_path / "capture"
    run_cli("synth", "--out", capture, "--lighting", "flash", "--light-intensity", 2.0, "--specular", 0,
            "--views", 8, "--resolution", 32, "--spp", 32, "--held-out", 2, check=True)
    strip_light(capture)
    scores = {}
    for mode in ("rig", "estimate"):
        run = tmp_path / mode
        proc = run_cli("reconstruct", capture, "--out", run, "--lighting", mode, *ESTIMATE_FAST, timeout=400,
                       env={"SFT_RECONSTRUCT_SETTINGS": json.dumps(ESTIMATE_SETTINGS)})
        assert proc.returncode == 0, proc.stderr[-3000:]
        lighting = json.loads((run / "report.json").read_text())["lighting"]
        assert lighting["frame"] == ("camera" if mode == "rig" else "world")
        scores[mode] = evaluate(run, capture)["views"]["held_out"]
    assert "fixed to the camera" in scores["rig"]["lighting"]
    assert scores["rig"]["psnr"] > 20 and scores["rig"]["psnr"] > scores["estimate"]["psnr"] + 1, scores
