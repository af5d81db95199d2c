"""Install Backend: the preferences' button makes a private interpreter in the extension's
user folder with the pinned requirements (real venv, real pip), reports the variant, and
becomes the automatic choice; offline and cancelled installs leave nothing behind."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from importlib import import_module
from pathlib import Path

import bpy

from .conftest import REPO

INSTALLER = REPO / "addon" / "io" / "install_backend.py"


def _installer(venv: Path, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(INSTALLER), "--venv", str(venv), "--requirements",
                             str(REPO / "backend" / "requirements.txt"), "--package", str(REPO)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, **(env or {})))


def _events(stdout: str) -> list[dict]:
    return [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]


def test_install_backend_button_sets_up_the_automatic_interpreter(context, extension):
    prefs = context.preferences.addons[extension.__name__].preferences
    preferences = import_module(f"{extension.__name__}.addon.preferences")
    venv = preferences.installed_venv()
    assert Path(bpy.utils.extension_path_user(extension.__name__)) in venv.parents
    chosen = prefs.python
    start = time.monotonic()
    assert bpy.ops.sft.install_backend() == {"FINISHED"}
    seconds = time.monotonic() - start
    assert (venv / "INSTALLED").is_file()
    assert prefs.check_result.startswith("OK: CPU, LLVM") or prefs.check_result.startswith("OK: CUDA"), \
        prefs.check_result
    prefs.python = ""
    try:
        python = preferences.backend_python(context)
        assert Path(python).parent.parent == venv, python
        assert bpy.ops.sft.check_backend() == {"FINISHED"}
        assert "mitsuba 3.9.1" in prefs.check_result
    finally:
        prefs.python = chosen
    print(f"Install Backend took {seconds:.0f} s")


def test_offline_install_fails_with_one_line_and_leaves_nothing(tmp_path):
    venv = tmp_path / "venv"
    # a package index that refuses connections: what pip meets without a network
    offline = {"PIP_INDEX_URL": "http://127.0.0.1:9/simple", "PIP_EXTRA_INDEX_URL": "", "PIP_FIND_LINKS": "",
               "PIP_CONFIG_FILE": os.devnull, "PIP_RETRIES": "0", "PIP_TIMEOUT": "2", "PIP_NO_CACHE_DIR": "1"}
    proc = _installer(venv, offline)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 2, err[-2000:]
    last = _events(out)[-1]
    assert last["event"] == "error" and "cannot reach the Python package index" in last["message"]
    assert "Fix:" in last["message"] and "\n" not in last["message"]
    assert not venv.exists()


def test_cancelled_install_leaves_nothing(tmp_path):
    venv = tmp_path / "venv"
    proc = _installer(venv)
    for line in proc.stdout:  # cancel once pip is downloading
        if '"stage": "download"' in line:
            break
    proc.terminate()
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert _events(out)[-1]["event"] == "cancelled"
    assert not venv.exists()
