"""Video frames through Blender's own movie loading: a temporary scene whose sequencer
holds the movie renders the chosen frames to PNG, colours unchanged (Standard view).
Blender's movie reader applies the video's display rotation (a phone's portrait video is
stored landscape with a rotation tag), so the frames come out upright.

Decoding happens in Blender's process (the sequencer is bpy data) but one frame at a time:
:func:`frame_steps` yields after each frame, so a modal timer interleaves it with the UI."""

from pathlib import Path

import bpy

from .io.errors import AddonInputError, require

VIDEO_SUFFIXES = {".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mts", ".mpg", ".mpeg", ".ogv"}


def video_info(path: str | Path) -> tuple[int, int, int, float]:
    """(frames, width, height, fps) of a video file."""
    path = Path(path)
    require(path.is_file(), path, "video not found", "choose a video file")
    require(path.suffix.lower() in VIDEO_SUFFIXES, path, "not a video file",
            f"choose one of {', '.join(sorted(VIDEO_SUFFIXES))}")
    try:
        clip = bpy.data.movieclips.load(str(path), check_existing=False)
    except RuntimeError as err:
        raise AddonInputError(path, "cannot read the video", "re-encode it as H.264 MP4") from err
    try:
        info = (clip.frame_duration, *clip.size, clip.fps)
    finally:
        bpy.data.movieclips.remove(clip)
    require(info[0] > 0 and info[1] > 0 and info[2] > 0, path, "the video has no readable frames",
            "re-encode it as H.264 MP4")
    return info


def render_frames(path: str | Path, frames: list[int], out_dir: str | Path, progress=None) -> list[Path]:
    """Write the 0-based ``frames`` of a video as PNGs in ``out_dir``; returns their paths.
    ``progress(done, total)`` is called after each frame."""
    steps = frame_steps(path, frames, out_dir)
    while True:
        try:
            done, total = next(steps)
        except StopIteration as end:
            return end.value
        if progress is not None:
            progress(done, total)


def frame_steps(path: str | Path, frames: list[int], out_dir: str | Path):
    """:func:`render_frames` as a generator: yields ``(done, total)`` after each frame and
    returns the paths; closing it early removes the temporary scene."""
    total, width, height, fps = video_info(path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = bpy.data.scenes.new(".sft_video")
    had_result = {image.name for image in bpy.data.images if image.type == "RENDER_RESULT"}
    try:
        editor = scene.sequence_editor_create()
        strips = editor.strips if hasattr(editor, "strips") else editor.sequences  # 4.4 renamed it
        strips.new_movie("video", str(path), channel=1, frame_start=1)
        render = scene.render
        render.resolution_x, render.resolution_y, render.resolution_percentage = width, height, 100
        render.fps = max(1, round(fps))
        render.use_sequencer = True
        render.image_settings.file_format = "PNG"
        render.image_settings.color_mode = "RGB"
        render.image_settings.color_depth = "8"
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        scene.view_settings.exposure = 0.0
        scene.view_settings.gamma = 1.0
        render.filepath = str(out_dir / "######")
        written = []
        for index in frames:  # a one-frame animation: still renders ignore the scene's frame
            scene.frame_start = scene.frame_end = index + 1
            target = out_dir / f"{index + 1:06d}.png"
            bpy.ops.render.render(animation=True, scene=scene.name)
            require(target.is_file(), path, f"frame {index} could not be decoded", "re-encode the video")
            written.append(target)
            yield len(written), len(frames)
        return written
    finally:
        bpy.data.scenes.remove(scene)
        for image in [i for i in bpy.data.images if i.type == "RENDER_RESULT" and i.name not in had_result]:
            bpy.data.images.remove(image)  # the sequencer's renders leave the scene's images as they were
