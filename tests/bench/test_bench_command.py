"""``python -m backend bench`` where backend/bench is absent (the extension zip leaves it out)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_bench_without_the_benchmarks_answers_in_one_line(tmp_path):
    shutil.copytree(REPO / "backend", tmp_path / "backend",
                    ignore=shutil.ignore_patterns("bench", "__pycache__"))
    assert (tmp_path / "backend" / "commands" / "bench.py").is_file()
    for args in (["bench"], ["bench", "geometry", "--quick"]):
        proc = subprocess.run([sys.executable, "-m", "backend", *args], cwd=tmp_path, capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.startswith("error: benchmarks ship with the source repository")
        assert len(proc.stderr.strip().splitlines()) == 1 and "Traceback" not in proc.stderr


def test_bench_lists_the_benchmarks():
    proc = subprocess.run([sys.executable, "-m", "backend", "bench", "--help"], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0 and "geometry" in proc.stdout and "sweep" in proc.stdout
