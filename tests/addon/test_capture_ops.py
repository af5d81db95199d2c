"""Capture operators in Blender: Import Video, Import Masks, Import Environment Map."""

from __future__ import annotations

import json
import math

import bpy
import numpy as np
import pytest
from PIL import Image

from .conftest import scene_state
from .media import box_blur, pattern, spot_env, write_image, write_video


@pytest.fixture
def video(tmp_path):
    """12 frames, frames 3 and 6 blurred."""
    frames = [box_blur(pattern(i)) if i in (3, 6) else pattern(i) for i in range(12)]
    return write_video(tmp_path / "phone.mp4", frames)


def expect_error(op, *words, **props):
    """The operator reports an error naming the problem and leaves the scene unchanged."""
    before = scene_state()
    with pytest.raises(RuntimeError) as err:
        op(**props)
    for word in words:
        assert word in str(err.value), str(err.value)
    assert scene_state() == before
    return str(err.value)


def test_import_video_every_nth_skips_blurred(context, video, tmp_path):
    capture = tmp_path / "cap"
    assert bpy.ops.sft.import_video(filepath=str(video), capture_dir=str(capture), every_nth=3, target_count=0,
                                    blur_threshold=0.5) == {"FINISHED"}
    manifest = json.loads((capture / "frames.json").read_text())
    assert [f["source_frame"] for f in manifest["frames"]] == [0, 9]  # 3 and 6 are blurred
    assert manifest["skipped_blurred"] == [3, 6] and manifest["video_frames"] == 12
    assert sorted(p.name for p in (capture / "images").iterdir()) == ["0000.png", "0001.png"]
    first = np.asarray(Image.open(capture / "images" / "0000.png").convert("RGB")).astype(int)
    assert first.shape == (48, 64, 3)
    assert np.abs(first - pattern(0)).mean() < 4  # colours pass through unchanged
    last = np.asarray(Image.open(capture / "images" / "0001.png").convert("RGB")).astype(int)
    assert np.abs(last - pattern(9)).mean() < 4
    assert context.scene.sft.capture_dir == str(capture)
    assert not [p for p in capture.iterdir() if p.name.startswith(".")]  # no temporary leftovers


def test_import_video_target_count_and_overwrite(context, video, tmp_path):
    capture = tmp_path / "cap"
    bpy.ops.sft.import_video(filepath=str(video), capture_dir=str(capture), target_count=4, blur_threshold=0)
    assert [f["source_frame"] for f in json.loads((capture / "frames.json").read_text())["frames"]] == [0, 4, 7, 11]
    expect_error(bpy.ops.sft.import_video, "already holds frames", "Overwrite",
                 filepath=str(video), capture_dir=str(capture), target_count=2)
    bpy.ops.sft.import_video(filepath=str(video), capture_dir=str(capture), target_count=2, blur_threshold=0,
                             overwrite=True)
    assert len(list((capture / "images").iterdir())) == 2


def test_import_video_bad_input(context, tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "broken.mp4").write_bytes(b"not a video at all")
    expect_error(bpy.ops.sft.import_video, "video not found", filepath=str(tmp_path / "none.mp4"))
    expect_error(bpy.ops.sft.import_video, "not a video file", filepath=str(tmp_path / "notes.txt"))
    expect_error(bpy.ops.sft.import_video, "broken.mp4", "Fix:", filepath=str(tmp_path / "broken.mp4"))


def _masks(folder, count, h=48, w=64, empty=False):
    folder.mkdir()
    for i in range(count):
        m = np.zeros((h, w, 3), np.float32)
        if not empty:
            m[8 + i % 5:30, 10:40] = 1.0
        write_image(folder / f"mask_{i}.png", m)
    return folder


def test_import_masks_per_video_frame_and_per_frame(context, video, tmp_path):
    capture = tmp_path / "cap"
    bpy.ops.sft.import_video(filepath=str(video), capture_dir=str(capture), every_nth=4, target_count=0, blur_threshold=0)
    # one mask per video frame: picked by each frame's source (0, 4, 8)
    masks = _masks(tmp_path / "all", 12)
    assert bpy.ops.sft.import_masks(filepath=str(masks / "mask_0.png")) == {"FINISHED"}
    for name, source in (("0000", 0), ("0001", 4), ("0002", 8)):
        m = np.asarray(Image.open(capture / "masks" / f"{name}.png"))
        assert m.dtype == np.uint8 and m.ndim == 2 and set(np.unique(m)) == {0, 255}
        assert m[8 + source % 5, 20] == 255 and m[7 + source % 5, 20] == 0
    # one mask per imported frame
    bpy.ops.sft.import_masks(filepath=str(_masks(tmp_path / "three", 3) / "mask_2.png"))
    assert np.asarray(Image.open(capture / "masks" / "0002.png"))[10, 20] == 255
    # per-material masks become integer labels, later imports painting over earlier ones
    for label, cols in ((2, slice(0, 40)), (5, slice(30, 64))):
        folder = tmp_path / f"material_{label}"
        folder.mkdir()
        for i in range(3):
            m = np.zeros((48, 64, 3), np.float32)
            m[:, cols] = 1.0
            write_image(folder / f"{i}.png", m)
        bpy.ops.sft.import_masks(filepath=str(folder / "0.png"), material=label)
    labels = np.asarray(Image.open(capture / "materials" / "0001.png"))
    assert labels.dtype == np.uint8 and labels.ndim == 2
    assert (labels[:, :30] == 2).all() and (labels[:, 30:] == 5).all()


def test_import_masks_from_a_mask_video(context, video, tmp_path):
    capture = tmp_path / "cap"
    bpy.ops.sft.import_video(filepath=str(video), capture_dir=str(capture), every_nth=5, target_count=0, blur_threshold=0)
    masks = []
    for i in range(12):  # one mask per video frame: a bar whose top row is the frame number
        m = np.zeros((48, 64, 3), np.uint8)
        m[i + 2:40, 8:56] = 255
        masks.append(m)
    mask_video = write_video(tmp_path / "masks.mp4", masks)
    assert bpy.ops.sft.import_masks(filepath=str(mask_video)) == {"FINISHED"}
    for name, source in (("0000", 0), ("0001", 5), ("0002", 10)):
        m = np.asarray(Image.open(capture / "masks" / f"{name}.png"))
        assert m[source + 2, 30] == 255 and m[source + 1, 30] == 0 and m[45, 30] == 0


def test_import_masks_bad_input(context, video, tmp_path):
    expect_error(bpy.ops.sft.import_masks, "poll() import a video or cameras first", filepath=str(tmp_path / "x.png"))
    capture = tmp_path / "cap"
    bpy.ops.sft.import_video(filepath=str(video), capture_dir=str(capture), every_nth=4, target_count=0, blur_threshold=0)
    expect_error(bpy.ops.sft.import_masks, "5 masks match neither the 3 frames nor the 12 video frames",
                 filepath=str(_masks(tmp_path / "five", 5) / "mask_0.png"))
    small = tmp_path / "small"
    small.mkdir()
    for i in range(3):
        write_image(small / f"{i}.png", np.ones((10, 10, 3), np.float32))
    expect_error(bpy.ops.sft.import_masks, "mask is 10x10, the frames are 64x48", filepath=str(small / "0.png"))
    expect_error(bpy.ops.sft.import_masks, "every mask is empty",
                 filepath=str(_masks(tmp_path / "empty", 3, empty=True) / "mask_0.png"))
    assert not (capture / "masks").exists()


def test_import_environment_builds_convention_chain(context, tmp_path):
    env = spot_env(tmp_path / "env.exr", 0.3, 0.4, width=64)
    assert bpy.ops.sft.import_environment(filepath=str(env), strength=2.5, rotation_z=30.0) == {"FINISHED"}
    tree = context.scene.world.node_tree
    out = next(n for n in tree.nodes if n.type == "OUTPUT_WORLD")
    chain = []
    node = out
    while node.inputs and node.inputs[0].is_linked:
        node = node.inputs[0].links[0].from_node
        chain.append(node)
    assert [n.type for n in chain] == ["BACKGROUND", "TEX_ENVIRONMENT", "MAPPING", "TEX_COORD"]
    background, texture, mapping, coords = chain
    assert background.inputs["Strength"].default_value == pytest.approx(2.5)
    assert texture.projection == "EQUIRECTANGULAR" and texture.image.filepath == str(env)
    assert mapping.vector_type == "POINT"
    assert tuple(mapping.inputs["Rotation"].default_value) == pytest.approx((0, 0, math.radians(30)))
    assert mapping.inputs["Vector"].links[0].from_socket.name == "Generated"
    assert context.scene.sft.env_strength == pytest.approx(2.5)


def test_import_environment_bad_input(context, tmp_path):
    square = write_image(tmp_path / "square.exr", np.ones((32, 32, 3), np.float32), float_exr=True)
    (tmp_path / "fake.hdr").write_bytes(b"#?RADIANCE\nnonsense")
    (tmp_path / "x.png").write_bytes(b"")
    expect_error(bpy.ops.sft.import_environment, "32x32, not 2:1", filepath=str(square))
    expect_error(bpy.ops.sft.import_environment, "not found", filepath=str(tmp_path / "none.exr"))
    expect_error(bpy.ops.sft.import_environment, "not an EXR or HDR", filepath=str(tmp_path / "x.png"))
    expect_error(bpy.ops.sft.import_environment, "fake.hdr", filepath=str(tmp_path / "fake.hdr"))
