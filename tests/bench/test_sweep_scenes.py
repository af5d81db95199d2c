"""The sweep's scene kinds beyond the point-lit dragon, the textured blob and the corner: the
HDR-lit armadillo (self-shadowing) and the video path (Cycles orbit video, capture-from-video,
the truth carried into the solved frame), each built for real at toy size."""

from __future__ import annotations

import numpy as np

from backend import variant
from backend.bench import _sweep_scenes as scenes
from backend.bench.sweep import add_arguments
from backend.capture.images import read_mask
from backend.capture.load import load_capture
from backend.events import null_emitter
from backend.geometry.mesh import load_mesh
from backend.synth.capture import SynthSpec, synthesize
from tests.helpers import shared_data


def test_the_default_sweep_covers_every_scene_kind():
    import argparse

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    default = parser.parse_args([]).scenes.split(",")
    assert default == ["dragon", "blob_env", "corner", "armadillo_env", "video"]
    assert all(name in scenes.SCENES for name in default)


def test_the_armadillo_scene_is_the_full_mesh_under_the_forest_map(tmp_path):
    shared_data("meshes", "stanford", "armadillo_86k.obj")
    variant.choose()
    spec = SynthSpec(**{**scenes.ARMADILLO_ENV, "views": 4, "resolution": 32, "spp": 8, "held_out": 1})
    synthesize(spec, tmp_path / "arma", null_emitter())
    capture = load_capture(tmp_path / "arma")
    assert capture.environment is not None and capture.environment.path.is_file()
    assert str(capture.provenance["spec"]["environment"]).endswith("forest_slope_1k.hdr"), capture.provenance
    assert not capture.has_point_lights and len(capture.frames) == 4
    truth = load_mesh(capture.path(capture.ground_truth["mesh"]))
    assert truth.n_faces > 50_000  # the full armadillo, not a stand-in
    assert {"held_out", "relit"} <= set(capture.ground_truth)


def test_the_video_scene_carries_the_truth_into_the_solved_frame(tmp_path):
    """The truth mesh, moved by the camera similarity, projects onto the frames' masks."""
    shared_data("meshes", "crane", "spot", "spot.obj")
    out = tmp_path / "scenes" / "video"
    out.mkdir(parents=True)
    scenes.build_video(out, null_emitter(), frames=12, size="192x108", samples=1)
    assert (tmp_path / "scenes" / "video_orbit" / "orbit" / "orbit.mp4").is_file()  # cached beside it
    capture = load_capture(out)
    assert capture.ground_truth == {"mesh": "gt/mesh.ply"} and capture.provenance["scene"] == "video"
    truth = load_mesh(capture.path("gt/mesh.ply"))
    inside = []
    for frame in capture.frames:
        cam, mask = frame.camera, read_mask(frame.mask)
        w2c = np.linalg.inv(cam.camera_to_world)
        p = truth.vertices @ w2c[:3, :3].T + w2c[:3, 3]  # OpenGL camera: looking down -z
        x = cam.fx * p[:, 0] / -p[:, 2] + cam.cx
        y = cam.cy - cam.fy * p[:, 1] / -p[:, 2]
        ok = (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height) & (p[:, 2] < 0)
        h, w = mask.shape
        cols = np.clip((x[ok] * w / cam.width).astype(int), 0, w - 1)
        rows = np.clip((y[ok] * h / cam.height).astype(int), 0, h - 1)
        inside.append(float(np.mean(mask[rows, cols] > 0.5)) if ok.any() else 0.0)
    assert len(inside) >= 3 and np.median(inside) > 0.9, inside
