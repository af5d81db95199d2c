"""Install Backend: the preferences' button makes a private interpreter in the extension's
user folder with the pinned requirements (real venv, real pip), reports the variant, and
becomes the automatic choice; offline and cancelled installs leave nothing behind and keep
the environment already installed as it was."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from importlib import import_module
from pathlib import Path

import bpy
import pytest

from addon.io.install_backend import installed_python

from .conftest import REPO

INSTALLER = REPO / "addon" / "io" / "install_backend.py"


def _installer(venv: Path, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(INSTALLER), "--venv", str(venv), "--requirements",
                             str(REPO / "backend" / "requirements.txt"), "--package", str(REPO)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, **(env or {})))


def _events(stdout: str) -> list[dict]:
    return [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]


OFFLINE = {"PIP_INDEX_URL": "http://127.0.0.1:9/simple", "PIP_EXTRA_INDEX_URL": "", "PIP_FIND_LINKS": "",
           "PIP_CONFIG_FILE": os.devnull, "PIP_RETRIES": "0", "PIP_TIMEOUT": "2", "PIP_NO_CACHE_DIR": "1"}


def _working_environment(venv: Path) -> dict:
    """An installed environment as Install Backend leaves it: a venv that imports the test
    interpreter's libraries (a .pth file) and its INSTALLED marker; returns its fingerprint."""
    import site

    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    (packages,) = venv.glob("lib/python*/site-packages") if sys.platform != "win32" else [venv / "Lib" / "site-packages"]
    (packages / "sft-test-libraries.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    python = venv / ("Scripts/python.exe" if sys.platform == "win32" else "bin/python")
    (venv / "INSTALLED").write_text(json.dumps({"python": str(python), "check": {"ok": True}}))
    return _fingerprint(venv)


def _fingerprint(venv: Path) -> dict:
    return {str(p.relative_to(venv)): p.stat().st_mtime_ns for p in venv.rglob("*") if not p.is_symlink()}


def _still_works(venv: Path, tmp_path: Path, before: dict) -> None:
    """The environment is where it was, unchanged, and still runs the backend; nothing else is left."""
    assert _fingerprint(venv) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [venv.name]
    python = installed_python(venv)
    assert python is not None and Path(python).parent.parent == venv
    proc = subprocess.run([str(python), "-m", "backend", "check"], capture_output=True, text=True, timeout=300,
                          cwd=str(REPO), env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert json.loads(proc.stdout.strip().splitlines()[-1])["ok"], proc.stdout[-2000:] + proc.stderr[-2000:]


def test_install_backend_button_sets_up_the_automatic_interpreter(context, extension):
    prefs = context.preferences.addons[extension.__name__].preferences
    preferences = import_module(f"{extension.__name__}.addon.preferences")
    venv = preferences.installed_venv()
    assert Path(bpy.utils.extension_path_user(extension.__name__)) in venv.parents
    chosen = prefs.python
    context.preferences.system.use_online_access = True  # the download needs it (off by default)
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


def test_install_backend_says_how_to_allow_online_access(context, extension):
    """Blender's Allow Online Access is off: no download is tried, one line says where to turn it on."""
    prefs = context.preferences.addons[extension.__name__].preferences
    venv = import_module(f"{extension.__name__}.addon.preferences").installed_venv()
    system = context.preferences.system
    allowed = system.use_online_access
    before = (venv / "INSTALLED").exists()  # an earlier test may have installed one
    system.use_online_access = False
    try:
        assert not bpy.app.online_access
        try:
            bpy.ops.sft.install_backend()
            raise AssertionError("Install Backend ran without online access")
        except RuntimeError as err:
            message = str(err)
    finally:
        system.use_online_access = allowed
    assert "does not allow online access" in message and "Fix:" in message
    assert "Preferences > System > Network > Allow Online Access" in message
    assert prefs.check_result.endswith("then press Install Backend again") and "\n" not in prefs.check_result
    # nothing was tried: the environment (or its absence) is as it was, and nothing was staged
    assert (venv / "INSTALLED").exists() == before and not venv.with_name(f".{venv.name}.installing").exists()


def test_offline_install_fails_with_one_line_and_leaves_nothing(tmp_path):
    venv = tmp_path / "venv"
    # a package index that refuses connections: what pip meets without a network
    proc = _installer(venv, OFFLINE)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 2, err[-2000:]
    last = _events(out)[-1]
    assert last["event"] == "error" and "cannot reach the Python package index" in last["message"]
    assert "Fix:" in last["message"] and "\n" not in last["message"]
    assert not venv.exists() and not any(tmp_path.iterdir())


def test_offline_reinstall_keeps_the_working_environment(tmp_path):
    """Install Backend pressed again without a network: the new environment is built beside
    the installed one and never replaces it, so the backend keeps running."""
    venv = tmp_path / "venv"
    before = _working_environment(venv)
    proc = _installer(venv, OFFLINE)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 2, err[-2000:]
    assert _events(out)[-1]["event"] == "error"
    _still_works(venv, tmp_path, before)


@pytest.mark.parametrize("installed", [False, True])
def test_cancelled_install_leaves_nothing(tmp_path, installed):
    venv = tmp_path / "venv"
    before = _working_environment(venv) if installed else None
    proc = _installer(venv)
    for line in proc.stdout:  # cancel once pip is downloading
        if '"stage": "download"' in line:
            break
    proc.terminate()
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert _events(out)[-1]["event"] == "cancelled"
    if installed:  # the environment in use stays as it was
        _still_works(venv, tmp_path, before)
    else:
        assert not venv.exists() and not any(tmp_path.iterdir())


def test_a_checked_environment_replaces_the_installed_one(tmp_path):
    """The switch at the end of a successful install: the new environment moves into the
    folder, the previous one is removed, and nothing else is left beside it."""
    from addon.io.install_backend import Installer, staging_folder

    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "old").write_text("previous environment")
    installer = Installer(venv, REPO / "backend" / "requirements.txt", REPO)
    staging = staging_folder(venv)
    (staging / "bin").mkdir(parents=True)
    (staging / "INSTALLED").write_text("{}")
    installer._switch()
    assert (venv / "INSTALLED").is_file() and not (venv / "old").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["venv"]
