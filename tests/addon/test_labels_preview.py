"""Preview Material Labels in Blender: the backend clusters a real synthetic capture's object
colours (``python -m backend labels``), the overlays land beside the frames, the frame cameras
show them and Show Labels switches back to the frames."""

from __future__ import annotations

import json
import shutil

import bpy
import numpy as np
import pytest
from PIL import Image

from backend.capture.images import read_mask
from tests.conftest import run_cli


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """The built-in object (a two-colour procedural texture) under the sky, 3 views at 48 px."""
    out = tmp_path_factory.mktemp("labels") / "capture"
    run_cli("synth", "--out", out, "--views", 3, "--resolution", 48, "--spp", 8, "--lighting", "env", "--env", "sky",
            "--format", "png", check=True)
    return out


def _backgrounds() -> dict[str, str]:
    cams = bpy.data.collections["SfT Cameras"].objects
    return {o["sft_frame"]: bpy.path.abspath(o.data.background_images[0].image.filepath) for o in cams}


def test_preview_labels_shows_the_clusters_on_the_frame_cameras(context, capture, capfd):
    assert bpy.ops.sft.import_cameras(filepath=str(capture / "capture.json")) == {"FINISHED"}
    frames = json.loads((capture / "capture.json").read_text())["frames"]
    assert bpy.ops.sft.preview_labels(materials=2) == {"FINISHED"}
    out, err = capfd.readouterr()
    assert "2 material labels (colour clusters" in out + err
    folder = capture / "labels_preview"
    overlays = sorted(folder.glob("*.png"))
    assert [p.stem for p in overlays] == sorted(f["name"] for f in frames)
    assert context.scene.sft.show_labels
    assert _backgrounds() == {p.stem: str(p) for p in overlays}
    assert bpy.data.images["SfT Material Labels"].size[:] == Image.open(overlays[0]).size
    # two palette colours over the object, the background darkened
    for frame in frames:
        overlay = np.asarray(Image.open(folder / f"{frame['name']}.png").convert("RGB"), np.float64)
        frame_rgb = np.asarray(Image.open(capture / frame["image"]).convert("RGB"), np.float64)
        obj = read_mask(capture / frame["mask"]) >= 0.5
        assert np.allclose(overlay[~obj], np.round(frame_rgb[~obj] / 3), atol=1)
        tint = overlay[obj] - 0.4 * frame_rgb[obj]  # the palette's share: 0.6 of labels 1 and 2
        red, green = np.array([230, 25, 75]) * 0.6, np.array([60, 180, 75]) * 0.6
        near = np.stack([np.abs(tint - red).max(1), np.abs(tint - green).max(1)]) < 2
        assert near.any(0).mean() > 0.99 and near.mean(1).min() > 0.05, near.mean(1)
    context.scene.sft.show_labels = False
    assert all(path == str(capture / f["image"]) or path.endswith(f["image"]) for path, f in
               zip((_backgrounds()[f["name"]] for f in frames), frames))


def test_preview_labels_needs_masks(context, capture, tmp_path):
    bare = shutil.copytree(capture, tmp_path / "bare", ignore=shutil.ignore_patterns("labels_preview"))
    doc = json.loads((bare / "capture.json").read_text())
    for f in doc["frames"]:
        f.pop("mask", None)
    (bare / "capture.json").write_text(json.dumps(doc))
    assert bpy.ops.sft.import_cameras(filepath=str(bare / "capture.json")) == {"FINISHED"}
    with pytest.raises(RuntimeError, match="no object mask"):
        bpy.ops.sft.preview_labels()
    assert not (bare / "labels_preview").exists()
