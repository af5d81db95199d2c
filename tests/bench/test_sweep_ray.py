"""``bench sweep --ray``: the smoke grid's two runs as Ray tasks on a local Ray instance
(``ray.init(num_cpus=2)``), gathered into results.jsonl, with the same figures as the same two
runs made locally (seeded runs of one machine: equal within run spread). Without Ray, --ray
is refused in one line (exit 2)."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from backend.bench import sweep
from tests.helpers import REPO


def _sweep(root, *extra):
    parser = argparse.ArgumentParser()
    sweep.add_arguments(parser)
    args = parser.parse_args(["--grid", "smoke", "--scenes", "tiny", "--out", str(root / "work"),
                              "--report", str(root / "report"), "--repeats", "1", "--eval-spp", "16", *extra])
    assert sweep.run(args) == 0
    return {r["name"]: r for r in sweep.load_results(root / "work" / "results.jsonl")}


def test_sweep_on_ray_matches_local(tmp_path):
    ray = pytest.importorskip("ray", reason="Ray is optional (pip install ray); the --ray path needs it")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"PYTHONPATH": str(REPO)}})
    try:
        on_ray = _sweep(tmp_path / "ray", "--ray", "--cpus-per-run", "1")
    finally:
        ray.shutdown()
    assert sorted(on_ray) == ["smoke-a", "smoke-b"]
    local = _sweep(tmp_path / "local")
    for name, row in on_ray.items():
        assert row["rc"] == 0, row.get("error")
        assert row["seconds"] > 0 and 0 < row["f1"] <= 100 and row["chamfer_l1"] > 0
        # seeded runs: the same surface up to Dr.Jit's parallel reductions
        assert abs(row["f1"] - local[name]["f1"]) <= 2.0, (name, row["f1"], local[name]["f1"])
        assert abs(row["chamfer_l1"] - local[name]["chamfer_l1"]) <= 0.1 * local[name]["chamfer_l1"]
        assert abs(row["novel_psnr"] - local[name]["novel_psnr"]) <= 0.5


def test_ray_missing_is_one_line(tmp_path):
    code = ("import sys, builtins; real = builtins.__import__\n"
            "def imp(name, *a, **k):\n"
            "    if name == 'ray' or name.startswith('ray.'): raise ImportError(name)\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = imp\n"
            "from backend.cli import main; sys.exit(main())")
    proc = subprocess.run([sys.executable, "-c", code, "bench", "sweep", "--grid", "smoke", "--scenes", "tiny",
                           "--out", str(tmp_path / "w"), "--ray"], cwd=REPO, capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Ray" in lines[0] and "pip install ray" in lines[0]
    assert not (tmp_path / "w" / "results.jsonl").exists()
