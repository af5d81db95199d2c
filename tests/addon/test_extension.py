"""The extension package: Blender's validator, build, install into a temporary repository,
enable, sidebar panels, preferences and the backend check."""

from __future__ import annotations

import ast
import json
import zipfile

import bpy

from .conftest import REPO, VALID_TAGS, blender_ext


def test_manifest_passes_blenders_validator():
    proc = blender_ext("validate", "--valid-tags", str(VALID_TAGS), str(REPO))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Success" in proc.stdout
    import tomllib

    permissions = tomllib.loads((REPO / "blender_manifest.toml").read_text())["permissions"]
    assert "340 MB" in permissions["network"], "Install Backend's download needs the network permission"


def test_zip_holds_addon_and_backend_only(built_zip):
    names = zipfile.ZipFile(built_zip).namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert "addon/operators/reconstruct.py" in names and "addon/ui/panels.py" in names
    assert "backend/__main__.py" in names and "backend/commands/check.py" in names
    assert "addon/io/preset_file.py" in names and "backend/presets.json" in names  # the Quality list's source
    for excluded in (".venv/", "tests/", "docs/", "scripts/", ".git/", "runs/", "bench/"):
        assert not any(n.startswith(excluded) for n in names), excluded
    assert not any("__pycache__" in n or n.endswith((".pyc", ".blend", ".zip")) for n in names)
    proc = blender_ext("validate", "--valid-tags", str(VALID_TAGS), str(built_zip))
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_installed_and_enabled(extension):
    assert extension.__file__.endswith("shape_from_tracing/__init__.py")
    assert "sft_tests" in extension.__name__
    assert hasattr(bpy.types.Scene, "sft")
    for op in ("import_video", "import_masks", "import_environment", "import_cameras", "solve_cameras",
               "reconstruct", "reconstruct_cancel", "relit_preview", "export_gltf", "check_backend",
               "install_backend", "install_backend_cancel", "solve_cameras_cancel"):
        assert hasattr(bpy.ops.sft, op), op
    panels = {name: getattr(bpy.types, name) for name in
              ("SFT_PT_capture", "SFT_PT_cameras", "SFT_PT_reconstruct", "SFT_PT_preview")}
    assert {p.bl_label for p in panels.values()} == {"Capture", "Cameras", "Reconstruct", "Preview"}
    assert all(p.bl_category == "Shape from Tracing" and p.bl_space_type == "VIEW_3D" for p in panels.values())


def test_addon_never_imports_heavy_libraries():
    for path in (REPO / "addon").rglob("*.py"):
        imported = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                imported.add(node.module.split(".")[0])
        assert not imported & {"mitsuba", "drjit", "pymeshlab", "pycolmap", "backend"}, path


def test_default_preset_calibration_shown(extension, context):
    from importlib import import_module

    preset_file = import_module(f"{extension.__name__}.addon.io.preset_file")
    calib = preset_file.calibration()
    expected = "not calibrated" if not (REPO / "backend" / "presets.json").is_file() else None
    text = preset_file.describe("balanced", calib)
    assert context.scene.sft.preset == "auto"  # the preset that fits the time budget
    assert text == expected if expected else text
    # the Quality list is the preset file's
    items = [item.identifier for item in context.scene.sft.bl_rna.properties["preset"].enum_items]
    assert items == ["auto", *(key for key, _, _ in preset_file.enum_items(calib))]
    if calib:
        assert items[1:] == list(json.loads((REPO / "backend" / "presets.json").read_text())["presets"])


def test_check_backend_button(extension, context):
    prefs = context.preferences.addons[extension.__name__].preferences
    assert bpy.ops.sft.check_backend() == {"FINISHED"}
    assert prefs.check_result.startswith("OK") and "mitsuba" in prefs.check_result
    good = prefs.python
    prefs.python = "/nonexistent/python"
    try:
        bpy.ops.sft.check_backend()
        raise AssertionError("expected an error report")
    except RuntimeError as err:
        assert "interpreter not found" in str(err)
    finally:
        prefs.python = good
    assert "interpreter not found" in prefs.check_result


def test_disable_and_enable_again(extension, context):
    import addon_utils

    name = extension.__name__
    python = context.preferences.addons[name].preferences.python
    addon_utils.disable(name, default_set=True)
    try:
        assert not hasattr(bpy.types.Scene, "sft") and not hasattr(bpy.types, "SFT_PT_capture")
    finally:
        addon_utils.enable(name, default_set=True)
        context.preferences.addons[name].preferences.python = python
    assert hasattr(bpy.types.Scene, "sft") and hasattr(bpy.types, "SFT_PT_reconstruct")
    assert bpy.ops.sft.check_backend() == {"FINISHED"}
