"""A run folder's final display mesh is rendered at the truth's held-out and relit views."""

import json
import shutil

from tests.helpers import run_cli


def test_ground_truth_as_a_run_scores_high_on_held_out_and_relit_views(tiny_capture, tmp_path):
    run = tmp_path / "run"
    (run / "snapshots").mkdir(parents=True)
    shutil.copy(tiny_capture / "gt" / "mesh.ply", run / "snapshots" / "000001.ply")
    shutil.copy(tiny_capture / "gt" / "mesh.ply", run / "result.ply")
    (run / "snapshot.json").write_text(json.dumps({"mesh": "snapshots/000001.ply"}))
    out = tmp_path / "evaluation.json"
    proc = run_cli("evaluate", run, "--truth", tiny_capture, "--out", out, "--samples", 20000, check=True)
    report = json.loads(out.read_text())
    assert "psnr held_out" in proc.stdout and "psnr relit" in proc.stdout
    for views in ("held_out", "relit"):  # the same mesh and material, rendered with other samples
        assert report["views"][views]["psnr"] > 30, report["views"][views]
    assert report["albedo"]["rmse"] < 1e-3
    assert sorted(p.name for p in (run / "renders" / "relit").iterdir()) == ["held00.exr", "held01.exr"]
