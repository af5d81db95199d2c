"""Capture operators: video to frames, masks, environment map.

Import Video and Import Masks are jobs (progress in the Capture panel, Cancel there):
their frame decoding goes through Blender's movie reader, which is bpy data and so runs
in Blender's process, chunked (one frame, or one mask, per timer step) rather than in a
child process that would need a second Blender to start. The work happens in a hidden
temporary folder that replaces the capture's only when complete, so a cancel leaves the
capture folder and the scene as they were."""

import json
import shutil
import tempfile
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from .. import capture_state, jobs, world
from ..io import frames as fr
from ..io.errors import AddonInputError, require
from ..io.files import png_bytes, replace_dir, write_atomic
from ..images import luminance, read_rgba
from ..video import VIDEO_SUFFIXES, frame_steps, video_info
from .common import abspath, capture_dir, fail, idle
from .modal import JobModal

CAPTURE_FILE = "capture.json"


def _idle(cls) -> bool:
    """Frames, masks and the map change under a running camera solve or reconstruction, or
    under another import: wait."""
    return idle(cls, "solve", "reconstruct", "video", "masks")


class _ImportJob(JobModal):
    """The file browser first (ImportHelper), then a chunked job: modal with a window, run
    to its end in a loop without one (scripts, background mode)."""

    def execute(self, context):
        if bpy.app.background or context.window is None:
            return JobModal.execute(self, context)
        return self.start_modal(context)

    def finish(self, context, job: jobs.TaskJob) -> set[str]:
        if job.error is not None:
            return fail(self, job.error)
        if job.state.status != "done":
            self.report({"WARNING"}, f"{self.bl_label} cancelled: the capture folder is unchanged")
            return {"CANCELLED"}
        self.report({"INFO"}, self.apply(context, job.result))
        return {"FINISHED"}


class SFT_OT_import_video(bpy.types.Operator, ImportHelper, _ImportJob):
    """Turn a phone video into frames (every Nth frame or a target count, blurred frames
    skipped); the frames go to the capture folder's images/"""

    bl_idname = "sft.import_video"
    bl_label = "Import Video"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(default=";".join(f"*{s}" for s in sorted(VIDEO_SUFFIXES)), options={"HIDDEN"})
    capture_dir: StringProperty(
        name="Capture Folder", subtype="DIR_PATH", default="",
        description="Where the frames go; empty: the scene's capture folder, else <video>_capture")
    every_nth: IntProperty(name="Every Nth Frame", default=10, min=1,
                           description="Keep every Nth frame (when Target Count is 0)")
    target_count: IntProperty(name="Target Count", default=40, min=0,
                              description="Frames to keep, spread evenly over the video, whatever its length "
                                          "(0: use Every Nth)")
    blur_threshold: FloatProperty(
        name="Blur Threshold", default=0.3, min=0.0, max=1.0,
        description="Skip frames less sharp than this fraction of the median sharpness (0: keep all)")
    overwrite: BoolProperty(name="Overwrite", default=False,
                            description="Replace frames (and their masks) already in the capture folder")

    job_kind = "video"

    @classmethod
    def poll(cls, context):
        return _idle(cls)

    def start(self, context) -> jobs.TaskJob:
        """Check the input (nothing is written on bad input), then the chunked job."""
        video = abspath(self.filepath)
        total, width, height, _ = video_info(video)
        if self.capture_dir or context.scene.sft.capture_dir:
            capture = capture_dir(context, self.capture_dir, must_exist=False)
        else:
            capture = video.with_name(f"{video.stem}_capture")
        images = capture / fr.IMAGES
        require(self.overwrite or not (images.is_dir() and any(images.iterdir())), images,
                "the capture folder already holds frames",
                "enable Overwrite or choose another capture folder")
        return jobs.TaskJob(self._extract(video, total, width, height, capture), self.job_kind)

    def apply(self, context, result) -> str:
        capture, kept, blurred = result
        context.scene.sft.capture_dir = str(capture)
        context.scene.sft.plan_text = ""  # new frames: the Plan line measured the old capture
        return f"{kept} frames in {capture / fr.IMAGES} ({blurred} blurred skipped)"

    def _extract(self, video: Path, total: int, width: int, height: int, capture: Path):
        """The task: decode the picked frames one per step, score their sharpness, then put
        the sharp ones in place at once."""
        made = not capture.exists()
        capture.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".import-", dir=capture))
        done = False
        try:
            picks = fr.pick_frames(total, self.every_nth, self.target_count)
            steps = frame_steps(video, picks, tmp / "video")
            try:
                while True:
                    n, count = next(steps)
                    yield {"stage": f"frame {n}/{count}", "fraction": 0.8 * n / count}
            except StopIteration as end:
                files = end.value
            finally:
                steps.close()
            scores = []
            for i, f in enumerate(files):
                scores.append(fr.sharpness(luminance(read_rgba(f)[0])))
                if i % 8 == 7:
                    yield {"stage": "sharpness", "fraction": 0.8 + 0.15 * i / len(files)}
            keep = fr.sharp_enough(scores, self.blur_threshold)
            out = tmp / fr.IMAGES
            out.mkdir()
            entries = []
            for source, file, score, ok in zip(picks, files, scores, keep):
                if ok:
                    name = fr.frame_name(len(entries))
                    file.rename(out / f"{name}.png")
                    entries.append({"name": name, "image": f"{fr.IMAGES}/{name}.png",
                                    "source_frame": source, "sharpness": score})
            replace_dir(out, capture / fr.IMAGES)
            for stale in (fr.MASKS, fr.MATERIALS):
                shutil.rmtree(capture / stale, ignore_errors=True)
            fr.write_manifest(capture, {
                "video": str(video), "video_frames": total, "width": width, "height": height,
                "frames": entries,
                "skipped_blurred": [s for s, ok in zip(picks, keep) if not ok]})
            done = True
            return capture, len(entries), len(picks) - len(entries)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            if made and not done:  # cancelled or failed: the folder this import made goes
                shutil.rmtree(capture, ignore_errors=True)


class SFT_OT_import_masks(bpy.types.Operator, ImportHelper, _ImportJob):
    """Import object masks (an image sequence or a video) matched to the imported frames;
    with a material label, the masks mark that material in materials/ instead"""

    bl_idname = "sft.import_masks"
    bl_label = "Import Masks"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(
        default=";".join(f"*{s}" for s in sorted(VIDEO_SUFFIXES | fr.IMAGE_SUFFIXES)), options={"HIDDEN"})
    material: IntProperty(
        name="Material Label", default=0, min=0, max=255,
        description="0: object masks (masks/). 1-255: these masks mark material N (materials/)")

    job_kind = "masks"

    @classmethod
    def poll(cls, context):
        if not _idle(cls):
            return False
        facts = capture_state.facts(context.scene)
        if not (facts.has_manifest or facts.has_capture_json):
            cls.poll_message_set("import a video or cameras first")
            return False
        return True

    def start(self, context) -> jobs.TaskJob:
        capture = capture_dir(context)
        source = abspath(self.filepath)
        if not (capture / fr.MANIFEST).is_file() and (capture / CAPTURE_FILE).is_file():
            task = self._import_onto_cameras(capture, source)
        else:
            task = self._import(capture, fr.read_manifest(capture), source)
        return jobs.TaskJob(task, self.job_kind)

    def apply(self, context, result) -> str:
        capture, written = result
        target = fr.MATERIALS if self.material else fr.MASKS
        context.scene.sft.plan_text = ""  # new masks: the Plan line measured the old capture
        return f"{written} masks in {capture / target}"

    def _masks_of(self, source: Path, picks: list[int], out_dir: Path):
        """Decode the ``picks`` of a mask video one per step (fraction up to 0.5); returns the files."""
        steps = frame_steps(source, picks, out_dir)
        try:
            while True:
                n, count = next(steps)
                yield {"stage": f"decoding mask {n}/{count}", "fraction": 0.5 * n / count}
        except StopIteration as end:
            return end.value
        finally:
            steps.close()

    def _import(self, capture: Path, manifest: dict, source: Path):
        frames = manifest["frames"]
        sources = [int(f["source_frame"]) for f in frames]
        size = (int(manifest["height"]), int(manifest["width"]))
        tmp = Path(tempfile.mkdtemp(prefix=".masks-", dir=capture))
        try:
            if source.suffix.lower() in VIDEO_SUFFIXES:
                count = video_info(source)[0]
                picks = fr.match_masks(count, sources, int(manifest.get("video_frames", 0)), source)
                files = yield from self._masks_of(source, picks, tmp / "video")
            else:
                sequence = fr.image_sequence(source)
                picks = fr.match_masks(len(sequence), sources, int(manifest.get("video_frames", 0)),
                                       sequence[0].parent)
                files = [sequence[i] for i in picks]
            target = fr.MATERIALS if self.material else fr.MASKS
            out = tmp / target
            out.mkdir()
            covered = 0
            for i, (frame, file) in enumerate(zip(frames, files)):
                covered += self._write_mask(file, size, "the frames are", out / f"{frame['name']}.png",
                                            capture / fr.MATERIALS / f"{frame['name']}.png")
                yield {"stage": f"mask {i + 1}/{len(frames)}", "fraction": 0.5 + 0.5 * (i + 1) / len(frames)}
            require(covered > 0, source, "every mask is empty", "masks mark the object in white (or alpha)")
            replace_dir(out, capture / target)
            return capture, len(frames)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    def _write_mask(self, file: Path, size: tuple[int, int], what: str, out: Path, previous: Path | None) -> bool:
        """Write one imported mask: a 0/255 object mask, or this Material Label painted into
        the ``previous`` label image. Returns whether the mask marks anything."""
        rgba = read_rgba(file)[0]
        require(rgba.shape[:2] == size, file, f"mask is {rgba.shape[1]}x{rgba.shape[0]}, {what} {size[1]}x{size[0]}",
                "export the masks at the frames' size")
        mask = fr.mask_from_rgba(rgba) > 0
        if self.material:
            labels = (np.rint(read_rgba(previous)[0][..., 0] * 255).astype(np.uint8)
                      if previous is not None and previous.is_file() else np.zeros(size, np.uint8))
            labels[mask] = self.material
            write_atomic(out, png_bytes(labels))
        else:
            write_atomic(out, png_bytes(mask.astype(np.uint8) * 255))
        return bool(mask.any())

    def _import_onto_cameras(self, capture: Path, source: Path):
        """Masks for a capture of imported cameras (capture.json): one per frame, in name
        order, written beside it and named in capture.json (``mask`` or ``material_mask``)."""
        path = capture / CAPTURE_FILE
        try:
            doc = json.loads(path.read_text())
            frames = doc["frames"]
            names = [str(f.get("name", f"{i:04d}")) for i, f in enumerate(frames)]
            sizes = [(int(f["camera"]["height"]), int(f["camera"]["width"])) for f in frames]
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise AddonInputError(path, "cannot read the capture's frames", "import the cameras again") from err
        tmp = Path(tempfile.mkdtemp(prefix=".masks-", dir=capture))
        try:
            if source.suffix.lower() in VIDEO_SUFFIXES:
                count = video_info(source)[0]
                require(count == len(frames), source, f"{count} masks for {len(frames)} frames",
                        "give one mask per frame of the capture")
                files = yield from self._masks_of(source, list(range(count)), tmp / "video")
            else:
                files = fr.image_sequence(source)
                require(len(files) == len(frames), files[0].parent, f"{len(files)} masks for {len(frames)} frames",
                        "give one mask per frame of the capture (paired in name order)")
            target, key = (fr.MATERIALS, "material_mask") if self.material else (fr.MASKS, "mask")
            out = tmp / target
            out.mkdir()
            covered = 0
            for i, (name, size, file) in enumerate(zip(names, sizes, files)):
                rel = f"{target}/{bpy.path.clean_name(name)}.png"
                previous = capture / frames[i]["material_mask"] if frames[i].get("material_mask") else None
                covered += self._write_mask(file, size, f"frame {name} is", tmp / rel, previous)
                frames[i][key] = rel
                yield {"stage": f"mask {i + 1}/{len(frames)}", "fraction": 0.5 + 0.5 * (i + 1) / len(frames)}
            require(covered > 0, source, "every mask is empty", "masks mark the object in white (or alpha)")
            replace_dir(out, capture / target)
            write_atomic(path, json.dumps(doc, indent=1).encode())
            return capture, len(frames)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


class SFT_OT_import_environment(bpy.types.Operator, ImportHelper):
    """Light the World with an equirectangular EXR/HDR map placed as the backend places it"""

    bl_idname = "sft.import_environment"
    bl_label = "Import Environment Map"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(default="*.exr;*.hdr", options={"HIDDEN"})
    strength: FloatProperty(name="Strength", default=1.0, min=0.0, soft_max=10.0,
                            description="Radiance multiplier (Background strength)")
    rotation_z: FloatProperty(name="Rotation Z", default=0.0, soft_min=-180.0, soft_max=180.0,
                              description="Rotation of the map about the world Z axis, degrees")

    @classmethod
    def poll(cls, context):
        return _idle(cls)

    def execute(self, context):
        try:
            image = world.load_environment_image(abspath(self.filepath))
        except AddonInputError as err:
            return fail(self, err)
        scene = context.scene
        if scene.world is None:
            scene.world = bpy.data.worlds.new("SfT World")
        world.set_environment(scene.world, image, self.strength, self.rotation_z)
        scene.sft.env_path = image.filepath
        scene.sft.lighting = "CAPTURED"
        scene.sft.plan_text = ""  # another map: the Plan line measured the old lighting
        scene.sft.env_strength = self.strength
        scene.sft.env_rotation = self.rotation_z
        self.report({"INFO"}, f"World lit by {Path(image.filepath).name}")
        return {"FINISHED"}


CLASSES = (SFT_OT_import_video, SFT_OT_import_masks, SFT_OT_import_environment)
