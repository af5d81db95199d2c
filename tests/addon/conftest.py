"""Fixtures for the add-on tests: Blender (the bpy module, imported here first, before any
pymeshlab) with the extension built from this repository, installed into a temporary
extensions repository and enabled. Nothing touches the real Blender user folders."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPTED_BACKEND = Path(__file__).resolve().parent / "scripted_backend"

if "bpy" not in sys.modules:  # user resources (config, extensions) in a temporary folder
    os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="sft-blender-user-")
import bpy  # noqa: E402

bpy.context.preferences.use_preferences_save = False

_SCRIPTS = Path(bpy.utils.system_resource("SCRIPTS"))
BLENDER_EXT = _SCRIPTS / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
VALID_TAGS = _SCRIPTS / "modules" / "_bpy_internal" / "extensions" / "tags.py"
REPO_MODULE = "sft_tests"


def blender_ext(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(BLENDER_EXT), *args], capture_output=True, text=True,
                          timeout=120)


@pytest.fixture(scope="session")
def built_zip(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    proc = blender_ext("build", "--source-dir", str(REPO), "--output-dir", str(out),
                       "--valid-tags", str(VALID_TAGS))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (zip_path,) = out.glob("*.zip")
    return zip_path


@pytest.fixture(scope="session")
def extension(built_zip, tmp_path_factory):
    """The installed, enabled extension package (``bl_ext.sft_tests.shape_from_tracing``)."""
    repo_dir = tmp_path_factory.mktemp("extensions")
    prefs = bpy.context.preferences
    if prefs.extensions.repos.get(REPO_MODULE) is None:  # repos are keyed by name
        prefs.extensions.repos.new(name=REPO_MODULE, module=REPO_MODULE,
                                   custom_directory=str(repo_dir), source="USER")
    result = bpy.ops.extensions.package_install_files(filepath=str(built_zip), repo=REPO_MODULE,
                                                      enable_on_install=True)
    assert result == {"FINISHED"}
    name = f"bl_ext.{REPO_MODULE}.shape_from_tracing"
    assert prefs.addons.get(name) is not None
    prefs.addons[name].preferences.python = sys.executable  # the venv: it imports mitsuba
    return sys.modules[name]


@pytest.fixture
def context(extension):
    """An empty scene with the extension enabled."""
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context


@pytest.fixture
def addon(extension):
    """The installed extension's ``addon`` package (its bpy-free and bpy modules)."""
    import importlib

    for name in ("jobs", "scene_mesh", "io.ply", "preview", "export", "io.capture_file", "scene_cameras"):
        importlib.import_module(f"{extension.__name__}.addon.{name}")
    return extension.addon


def scene_state() -> dict:
    """A fingerprint of the scene and data that operators must leave alone on bad input."""
    scene = bpy.context.scene
    return {
        "objects": sorted(o.name for o in bpy.data.objects),
        "meshes": sorted(m.name for m in bpy.data.meshes),
        "cameras": sorted(c.name for c in bpy.data.cameras),
        "images": sorted(i.name for i in bpy.data.images),
        "worlds": sorted(w.name for w in bpy.data.worlds),
        "world": scene.world.name if scene.world else None,
        "settings": {k: getattr(scene.sft, k) for k in scene.sft.bl_rna.properties.keys() if k != "rna_type"},
    }
