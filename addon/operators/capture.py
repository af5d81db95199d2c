"""Capture operators: video to frames, masks, environment map."""

import json
import shutil
import tempfile
from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from .. import world
from ..io import frames as fr
from ..io.errors import AddonInputError, require
from ..io.files import png_bytes, replace_dir, write_atomic
from ..images import luminance, read_rgba
from ..video import VIDEO_SUFFIXES, render_frames, video_info
from .common import Busy, abspath, capture_dir, fail, idle

CAPTURE_FILE = "capture.json"


def _idle(cls) -> bool:
    """Frames, masks and the map change under a running camera solve or reconstruction: wait."""
    return idle(cls, "solve", "reconstruct")


class SFT_OT_import_video(bpy.types.Operator, ImportHelper):
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

    @classmethod
    def poll(cls, context):
        return _idle(cls)

    def execute(self, context):
        try:
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
            with Busy(context, "Import Video") as busy:
                kept, blurred = self._extract(video, total, width, height, capture, busy)
        except AddonInputError as err:
            return fail(self, err)
        context.scene.sft.capture_dir = str(capture)
        context.scene.sft.plan_text = ""  # new frames: the Plan line measured the old capture
        self.report({"INFO"}, f"{kept} frames in {capture / fr.IMAGES} ({blurred} blurred skipped)")
        return {"FINISHED"}

    def _extract(self, video: Path, total: int, width: int, height: int, capture: Path, busy):
        capture.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".import-", dir=capture))
        try:
            picks = fr.pick_frames(total, self.every_nth, self.target_count)
            files = render_frames(video, picks, tmp / "video",
                                  lambda done, n: busy(0.8 * done, n, f"frame {done}/{n}"))
            scores = [fr.sharpness(luminance(read_rgba(f)[0])) for f in files]
            busy(0.9, 1.0, "sharpness")
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
            return len(entries), len(picks) - len(entries)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


class SFT_OT_import_masks(bpy.types.Operator, ImportHelper):
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

    @classmethod
    def poll(cls, context):
        if not _idle(cls):
            return False
        sft = context.scene.sft
        capture = abspath(sft.capture_dir) if sft.capture_dir else None
        if capture is None or not ((capture / fr.MANIFEST).is_file() or (capture / CAPTURE_FILE).is_file()):
            cls.poll_message_set("import a video or cameras first")
            return False
        return True

    def execute(self, context):
        try:
            capture = capture_dir(context)
            source = abspath(self.filepath)
            with Busy(context, "Import Masks"):
                if not (capture / fr.MANIFEST).is_file() and (capture / CAPTURE_FILE).is_file():
                    written = self._import_onto_cameras(capture, source)
                else:
                    written = self._import(capture, fr.read_manifest(capture), source)
        except AddonInputError as err:
            return fail(self, err)
        target = fr.MATERIALS if self.material else fr.MASKS
        context.scene.sft.plan_text = ""  # new masks: the Plan line measured the old capture
        self.report({"INFO"}, f"{written} masks in {capture / target}")
        return {"FINISHED"}

    def _import(self, capture: Path, manifest: dict, source: Path) -> int:
        frames = manifest["frames"]
        sources = [int(f["source_frame"]) for f in frames]
        size = (int(manifest["height"]), int(manifest["width"]))
        tmp = Path(tempfile.mkdtemp(prefix=".masks-", dir=capture))
        try:
            if source.suffix.lower() in VIDEO_SUFFIXES:
                count = video_info(source)[0]
                picks = fr.match_masks(count, sources, int(manifest.get("video_frames", 0)), source)
                files = render_frames(source, picks, tmp / "video")
            else:
                sequence = fr.image_sequence(source)
                picks = fr.match_masks(len(sequence), sources, int(manifest.get("video_frames", 0)),
                                       sequence[0].parent)
                files = [sequence[i] for i in picks]
            target = fr.MATERIALS if self.material else fr.MASKS
            out = tmp / target
            out.mkdir()
            covered = sum(self._write_mask(file, size, "the frames are", out / f"{frame['name']}.png",
                                           capture / fr.MATERIALS / f"{frame['name']}.png")
                          for frame, file in zip(frames, files))
            require(covered > 0, source, "every mask is empty", "masks mark the object in white (or alpha)")
            replace_dir(out, capture / target)
            return len(frames)
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

    def _import_onto_cameras(self, capture: Path, source: Path) -> int:
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
                files = render_frames(source, list(range(count)), tmp / "video")
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
            require(covered > 0, source, "every mask is empty", "masks mark the object in white (or alpha)")
            replace_dir(out, capture / target)
            write_atomic(path, json.dumps(doc, indent=1).encode())
            return len(frames)
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
