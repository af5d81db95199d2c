"""Camera operators: import solved cameras, or solve them with the backend's SfM."""

from pathlib import Path

import bpy
from bpy.props import BoolProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from .. import capture_file, interpreter, jobs, progress, world
from .. import frames as fr
from ..errors import AddonInputError, require
from ..preferences import backend_python
from .common import abspath, capture_dir, fail
from .modal import JobModal


def load_cameras(context, info: capture_file.CaptureInfo, show_frames: bool, with_environment: bool) -> str:
    """Put a read capture into the scene; returns a summary. Validates before changing anything."""
    from ..scene_cameras import create_cameras

    env_image = None
    if with_environment and info.environment:
        env_image = world.load_environment_image(info.environment["path"])
    create_cameras(context, info, show_frames)
    scene = context.scene
    scene.sft.capture_dir = str(info.root)
    if env_image is not None:
        if scene.world is None:
            scene.world = bpy.data.worlds.new("SfT World")
        env = info.environment
        world.set_environment(scene.world, env_image, env["strength"], env["rotation_z_deg"])
        scene.sft.env_path = str(env["path"])
        scene.sft.env_strength, scene.sft.env_rotation = env["strength"], env["rotation_z_deg"]
    return f"{len(info.frames)} cameras from {info.root}" + (", environment lit" if env_image else "")


class SFT_OT_import_cameras(bpy.types.Operator, ImportHelper):
    """Import cameras from capture.json, or (through the backend's importer) from a NeRF
    transforms.json or a COLMAP model"""

    bl_idname = "sft.import_cameras"
    bl_label = "Import Cameras"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: StringProperty(default="*.json;*.bin;*.txt;*.npz", options={"HIDDEN"})
    out_dir: StringProperty(
        name="Capture Folder", subtype="DIR_PATH", default="",
        description="Where other layouts are converted to a capture (empty: <source folder>/capture)")
    show_frames: BoolProperty(name="Show Frames", default=True,
                              description="Show each frame as its camera's background image")
    with_environment: BoolProperty(name="Environment", default=True,
                                   description="Light the World with the capture's environment map")

    def execute(self, context):
        try:
            source = abspath(self.filepath)
            require(source.exists(), source, "file not found", "choose capture.json, transforms.json or a COLMAP model")
            if source.name == capture_file.FILENAME or (source / capture_file.FILENAME).is_file():
                info = capture_file.read_capture(source)
            else:
                info = capture_file.read_capture(self._convert(context, source))
            summary = load_cameras(context, info, self.show_frames, self.with_environment)
        except AddonInputError as err:
            return fail(self, err)
        self.report({"INFO"}, summary)
        return {"FINISHED"}

    def _convert(self, context, source: Path) -> Path:
        require(interpreter.has_command("import"), source,
                "the backend beside the add-on has no 'import' command to convert this layout",
                "update the add-on, or convert the cameras to capture.json")
        folder = source if source.is_dir() else source.parent
        out = abspath(self.out_dir) if self.out_dir else folder / "capture"
        code, message = interpreter.run(backend_python(context), ["import", str(source), "--out", str(out)])
        require(code == 0, source if code != 2 else None, message or f"backend import failed (exit {code})")
        return out


class SFT_OT_solve_cameras(JobModal, bpy.types.Operator):
    """Solve camera poses from the imported video with the backend's structure from motion
    (python -m backend capture-from-video), then import them"""

    bl_idname = "sft.solve_cameras"
    bl_label = "Solve Cameras"
    bl_options = {"REGISTER", "UNDO"}

    job_kind = "solve"

    def start(self, context) -> jobs.Job:
        capture = capture_dir(context)
        manifest = fr.read_manifest(capture)
        require(interpreter.has_command("capture-from-video"), None,
                "the backend beside the add-on has no 'capture-from-video' command (camera solving)",
                "update the add-on, or solve the cameras elsewhere and use Import Cameras")
        video = Path(manifest["video"])
        require(video.is_file(), video, "the imported video is gone", "import the video again")
        self.out = capture / "solved"
        python = backend_python(context)
        accepts = interpreter.command_options(python, "capture-from-video")
        args = ["capture-from-video", str(video), "--out", str(self.out)]
        if "--overwrite" in accepts:  # solving again replaces the earlier solution
            args.append("--overwrite")
        if (capture / fr.MASKS).is_dir() and "--masks" in accepts:
            args += ["--masks", str(capture / fr.MASKS)]
        sft = context.scene.sft
        if sft.env_path and "--env" in accepts:
            args += ["--env", bpy.path.abspath(sft.env_path)]
            for flag, value in (("--env-strength", sft.env_strength), ("--env-rotation", sft.env_rotation)):
                if flag in accepts:
                    args += [flag, str(value)]
        return jobs.Job(python, args, self.out, kind=self.job_kind)

    def finish(self, context, job: jobs.Job):
        if job.state.status != "done":
            self.report({"ERROR"}, f"camera solving {job.state.status}: {job.state.message}")
            return {"CANCELLED"}
        try:
            summary = load_cameras(context, capture_file.read_capture(self.out), True, True)
        except AddonInputError as err:
            return fail(self, err)
        cameras = progress.cameras_summary(job.state.done)
        self.report({"INFO"}, f"solved: {summary}" + (f"; {cameras}" if cameras else ""))
        return {"FINISHED"}


CLASSES = (SFT_OT_import_cameras, SFT_OT_solve_cameras)
