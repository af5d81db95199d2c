"""Camera operators: import solved cameras, or solve them with the backend's SfM."""


import bpy
from bpy.props import BoolProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from .. import capture_state, jobs, world
from ..io import capture_file, interpreter, progress
from ..io import frames as fr
from ..io.errors import AddonInputError, require
from ..preferences import backend_python
from .common import abspath, capture_dir, fail, has_backend, idle
from .modal import CancelJob, JobModal


def load_cameras(context, info: capture_file.CaptureInfo, show_frames: bool, with_environment: bool) -> str:
    """Put a read capture into the scene; returns a summary. Validates before changing anything."""
    from ..scene_cameras import create_cameras

    env_image = None
    if with_environment and info.environment:
        env_image = world.load_environment_image(info.environment["path"])
    create_cameras(context, info, show_frames)
    scene = context.scene
    scene.sft.capture_dir = str(info.root)
    scene.sft.plan_text = ""  # new cameras: the Plan line measured the old ones
    lights = sum(len(frame.lights) for frame in info.frames)
    if lights:  # the capture's own point lights light it
        scene.sft.lighting = "CAPTURED"
    if env_image is not None:
        if scene.world is None:
            scene.world = bpy.data.worlds.new("SfT World")
        env = info.environment
        world.set_environment(scene.world, env_image, env["strength"], env["rotation_z_deg"])
        scene.sft.env_path = str(env["path"])
        scene.sft.lighting = "CAPTURED"
        scene.sft.env_strength, scene.sft.env_rotation = env["strength"], env["rotation_z_deg"]
    return (f"{len(info.frames)} cameras from {info.root}" + (", environment lit" if env_image else "")
            + (f", {lights} point lights" if lights else ""))


class SFT_OT_import_cameras(bpy.types.Operator, ImportHelper, JobModal):
    """Import cameras from capture.json, or (through the backend's importer, in the
    background) from a NeRF transforms.json, a COLMAP model, an IDR npz or Middlebury files"""

    bl_idname = "sft.import_cameras"
    bl_label = "Import Cameras"
    bl_options = {"REGISTER", "UNDO"}

    job_kind = "import"

    filter_glob: StringProperty(default="*.json;*.bin;*.txt;*.npz", options={"HIDDEN"})
    out_dir: StringProperty(
        name="Capture Folder", subtype="DIR_PATH", default="",
        description="Where other layouts are converted to a capture (empty: <source folder>/capture)")
    show_frames: BoolProperty(name="Show Frames", default=True,
                              description="Show each frame as its camera's background image")
    with_environment: BoolProperty(name="Environment", default=True,
                                   description="Light the World with the capture's environment map")

    @classmethod
    def poll(cls, context):
        return idle(cls, "import")

    def execute(self, context):
        try:
            source = abspath(self.filepath)
            require(source.exists(), source, "file not found", "choose capture.json, transforms.json or a COLMAP model")
            if source.name == capture_file.FILENAME or (source / capture_file.FILENAME).is_file():
                summary = load_cameras(context, capture_file.read_capture(source), self.show_frames,
                                       self.with_environment)
                self.report({"INFO"}, summary)
                return {"FINISHED"}
        except AddonInputError as err:
            return fail(self, err)
        if bpy.app.background or context.window is None:  # other layouts: the backend converts them
            return JobModal.execute(self, context)
        return self.start_modal(context)

    def start(self, context) -> jobs.Job:
        source = abspath(self.filepath)
        require(interpreter.has_command("import"), source,
                "the backend beside the add-on has no 'import' command to convert this layout",
                "update the add-on, or convert the cameras to capture.json")
        folder = source if source.is_dir() else source.parent
        self.out = abspath(self.out_dir) if self.out_dir else folder / "capture"
        return jobs.Job(backend_python(context), ["import", str(source), "--out", str(self.out)], None,
                        kind=self.job_kind)

    def finish(self, context, job: jobs.Job):
        if job.state.status != "done":
            self.report({"ERROR"}, f"importing cameras {job.state.status}: {job.state.message}")
            return {"CANCELLED"}
        try:
            summary = load_cameras(context, capture_file.read_capture(self.out), self.show_frames,
                                   self.with_environment)
        except AddonInputError as err:
            return fail(self, err)
        self.report({"INFO"}, summary)
        return {"FINISHED"}


def _imported_masks(capture) -> bool:
    return (capture / fr.MASKS).is_dir() and any((capture / fr.MASKS).glob("*.png"))


class SFT_OT_solve_cameras(JobModal, bpy.types.Operator):
    """Solve camera poses from the imported video with the backend's structure from motion
    (python -m backend capture-from-video), then import them"""

    bl_idname = "sft.solve_cameras"
    bl_label = "Solve Cameras"
    bl_options = {"REGISTER", "UNDO"}

    job_kind = "solve"

    @classmethod
    def poll(cls, context):
        if not idle(cls, cls.job_kind, "reconstruct", "plan"):  # they read the capture this rewrites
            return False
        facts = capture_state.facts(context.scene)  # poll runs on every redraw: no file reads
        if not facts.has_manifest:
            cls.poll_message_set("import a video first (Import Video)")
            return False
        if context.scene.sft.masks_mode == "IMPORTED" and not facts.masks:
            cls.poll_message_set("import the object masks first (Import Masks), or set Masks to Automatic")
            return False
        return has_backend(cls, context)

    def start(self, context) -> jobs.Job:
        capture = capture_dir(context)
        fr.read_manifest(capture)
        require(interpreter.has_command("capture-from-video"), None,
                "the backend beside the add-on has no 'capture-from-video' command (camera solving)",
                "update the add-on, or solve the cameras elsewhere and use Import Cameras")
        images, masks = capture / fr.IMAGES, capture / fr.MASKS
        require(images.is_dir() and any(images.glob("*.png")), images, "no frames", "import the video again")
        automatic = context.scene.sft.masks_mode == "AUTOMATIC" and not _imported_masks(capture)
        require(automatic or _imported_masks(capture), masks, "no masks",
                "import the object masks (Import Masks) before solving, or set Masks to Automatic")
        self.out = capture / "solved"
        # the kept frames with their masks, one each and paired by name order; none: made from the SfM result
        args = ["capture-from-video", "--images", str(images), "--out", str(self.out), "--overwrite"]
        if not automatic:
            args += ["--masks", str(masks)]
        if (capture / fr.MATERIALS).is_dir() and any((capture / fr.MATERIALS).glob("*.png")):
            args += ["--materials", str(capture / fr.MATERIALS)]  # per-material masks become material labels
        sft = context.scene.sft
        if sft.env_path:  # the map is aligned to the frames (rotation and strength estimated)
            args += ["--env", str(abspath(sft.env_path))]
        python = backend_python(context)
        return jobs.Job(python, args, None, kind=self.job_kind)  # a stop is a SIGTERM: nothing half-written stays

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


class SFT_OT_solve_cameras_cancel(CancelJob, bpy.types.Operator):
    """Stop camera solving (the capture folder is left as it was)"""

    bl_idname = "sft.solve_cameras_cancel"
    bl_label = "Cancel"
    job_kind = "solve"


CLASSES = (SFT_OT_import_cameras, SFT_OT_solve_cameras, SFT_OT_solve_cameras_cancel)
