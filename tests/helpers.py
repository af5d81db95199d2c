"""Helpers shared by test folders: paths and the CLI runner (import as ``tests.helpers``)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("SFT_SHARED_DATA", REPO.parent / "shared" / "data"))  # override for other checkouts


def shared_data(*parts: str) -> Path:
    """A path inside ../shared/data, or skip the test when the shared data is absent."""
    path = SHARED.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared data not available: {path}")
    return path


def run_cli(*args, timeout: float = 600, check: bool = False, cwd: Path | None = None,
            env: dict | None = None) -> subprocess.CompletedProcess:
    """Run ``python -m backend ARGS`` in a subprocess, capturing text output (``env``: extra
    environment variables)."""
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1", **(env or {}))
    proc = subprocess.run([sys.executable, "-m", "backend", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=cwd or REPO)
    if check and proc.returncode != 0:
        raise AssertionError(f"backend {args} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return proc


def withheld_map_capture(root: Path, views: int, resolution: int, spp: int, env: Path) -> tuple[Path, Path]:
    """A capture synthesised under the HDR map ``env`` in ``root``/lit, and its copy without
    the environment in ``root``/dark (a capture with no light: --lighting estimate's case).
    Returns (the dark capture, the lit capture's map)."""
    run_cli("synth", "--out", root / "lit", "--lighting", "env", "--env", env, "--views", views,
            "--resolution", resolution, "--spp", spp, "--held-out", 0, check=True)
    shutil.copytree(root / "lit", root / "dark")
    data = json.loads((root / "dark" / "capture.json").read_text())
    data.pop("environment")
    (root / "dark" / "capture.json").write_text(json.dumps(data))
    return root / "dark", root / "lit" / "env.exr"
