"""Frames: sources (video, folder), stride/count selection, blur rejection, index bookkeeping."""

from __future__ import annotations

import numpy as np
import pytest

from backend.errors import InputError
from backend.video.frames import check_masks, open_source, pick_frames, select
from tests.video.media import match_index, moving_frames, write_video

W, H, N = 96, 64, 40
BLURRED = (5, 6, 12, 13, 14, 15, 33)


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("video") / "orbit.mp4", moving_frames(N, W, H, blurred=BLURRED))


def test_select_bins_by_stride_and_count():
    sharp = np.ones(40)
    sharp[[4, 5, 6, 7]] = 0.1  # a whole stride-4 bin blurred
    sharp[9] = 0.2
    sharp[10] = 1.5
    by_stride = select(sharp, stride=4)
    assert by_stride.rejected == [4]  # the bin's sharpest frame, still too blurred
    assert len(by_stride.indices) == 9 and 10 in by_stride.indices and 9 not in by_stride.indices
    assert all(i // 4 == k for i, k in zip(by_stride.indices, [0, 2, 3, 4, 5, 6, 7, 8, 9]))
    by_count = select(sharp, count=8)
    assert len(by_count.indices) + len(by_count.rejected) == 8
    assert all(sharp[i] >= 0.5 for i in by_count.indices)
    assert select(sharp, stride=4, blur_ratio=0).indices == [0, 4, 10, 12, 16, 20, 24, 28, 32, 36]


def test_video_source_picks_sharp_frames_and_keeps_indices(video):
    source = open_source(video)
    assert (source.count, source.width, source.height, source.is_video) == (N, W, H, True)
    chosen = pick_frames(source, stride=4)
    assert len(chosen.sharpness) == N
    assert not set(chosen.indices) & set(BLURRED)
    assert chosen.rejected == [12]  # frames 12..15 are all blurred
    assert len(chosen.indices) == N // 4 - 1
    decoded = dict(source.frames(chosen.indices))
    assert sorted(decoded) == chosen.indices
    for index, rgb in decoded.items():  # what was decoded is the frame the index names
        assert rgb.shape == (H, W, 3)
        assert match_index(rgb, W, H, N) == index
    counted = pick_frames(source, count=10)
    assert len(counted.indices) + len(counted.rejected) == 10
    assert not set(counted.indices) & set(BLURRED)


def test_mask_video_pairs_by_index(video, tmp_path):
    frames = []
    for i in range(N):  # mask i: a white bar at column 2 i
        mask = np.zeros((H, W, 3), np.uint8)
        mask[:, 2 * i:2 * i + 8] = 255
        frames.append(mask)
    masks = open_source(write_video(tmp_path / "masks.mp4", frames))
    check_masks(open_source(video), masks)
    for i, mask in masks.masks([3, 17, 30]):
        assert mask.shape == (H, W) and mask.dtype == np.float32
        columns = np.flatnonzero(mask.mean(0) > 0.5)
        assert columns.min() == pytest.approx(2 * i, abs=1) and columns.max() == pytest.approx(2 * i + 7, abs=1)


def test_folder_source_sorts_numbers_naturally_and_reads_alpha_masks(tmp_path):
    from PIL import Image

    for i in (1, 2, 10):
        Image.fromarray(np.full((H, W, 3), i * 20, np.uint8)).save(tmp_path / f"frame_{i}.png")
    source = open_source(tmp_path)
    assert [f.name for f in source.files] == ["frame_1.png", "frame_2.png", "frame_10.png"]
    assert [int(rgb[0, 0, 0]) for _, rgb in source.frames()] == [20, 40, 200]
    masks_dir = tmp_path / "masks"
    masks_dir.mkdir()
    for i in range(3):
        rgba = np.zeros((H, W, 4), np.uint8)
        rgba[..., 3] = 255 * (i % 2)  # object only in frame 1, by alpha (RGB stays black)
        Image.fromarray(rgba).save(masks_dir / f"m{i}.png")
    assert [float(m.mean()) for _, m in open_source(masks_dir).masks()] == [0.0, 1.0, 0.0]


def test_mask_count_and_size_mismatch_rejected(video, tmp_path):
    from PIL import Image

    for i in range(N - 1):
        Image.fromarray(np.zeros((H, W), np.uint8)).save(tmp_path / f"{i:03d}.png")
    with pytest.raises(InputError, match=f"{N - 1} masks for {N} frames"):
        check_masks(open_source(video), open_source(tmp_path))
    Image.fromarray(np.zeros((H, W), np.uint8)).save(tmp_path / "zzz.png")
    check_masks(open_source(video), open_source(tmp_path))
    small = tmp_path / "small"
    small.mkdir()
    for i in range(N):
        Image.fromarray(np.zeros((H // 2, W // 2), np.uint8)).save(small / f"{i:03d}.png")
    with pytest.raises(InputError, match=f"masks are {W // 2}x{H // 2} but the frames are {W}x{H}"):
        check_masks(open_source(video), open_source(small))
