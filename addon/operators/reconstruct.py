"""Reconstruct: the backend refines mesh and material in its own process while the newest
snapshot streams into the "Reconstruction" object. Resume continues an unfinished run
(cancelled, or ended by a crash) from its last snapshot with the options it started with."""

import json
import shlex
import time
from pathlib import Path

import bpy
from bpy.props import StringProperty

from .. import capture_state, jobs, scene_mesh, world
from ..io import interpreter, progress
from ..io.errors import AddonInputError, require
from ..preferences import backend_python
from .common import abspath, capture_dir, has_backend, idle
from .modal import CancelJob, JobModal


def reconstruct_args(capture: Path, run: Path, preset: str | None, extra: str = "",
                     method: list[str] | tuple = ()) -> list[str]:
    """The backend command line (docs/protocol.md): ``reconstruct CAPTURE --out RUN ...``;
    ``method`` holds the panel's settings, ``extra`` (Advanced) comes last and wins."""
    try:
        options = shlex.split(extra)
    except ValueError as err:
        raise AddonInputError(None, f"extra arguments: {err}", "fix the quoting") from err
    return ["reconstruct", str(capture), "--out", str(run), *(["--preset", preset] if preset else []),
            *method, *options]


INIT_OPTIONS = {"CARVE": "carve", "SPHERE": "sphere", "POINTS": "points"}


# the Lighting settings that name a backend --lighting (CAPTURED passes the imported map, or nothing)
LIGHTING_OPTIONS = {"AUTO": "auto", "ESTIMATE": "estimate", "RIG": "rig", "WORLD_RIG": "world+rig", "FLASH": "flash"}


def method_args(sft, init_mesh: Path | None = None) -> list[str]:
    """The panel's method settings as backend options: budget, accuracy tracking, material, start,
    effects, lighting."""
    args = []
    if sft.time_budget > 0:
        args += ["--time-budget", f"{sft.time_budget:g}"]
    if sft.track_accuracy:
        args += ["--track-accuracy"]
    args += ["--material", "staged" if sft.material == "FULL" else "constant"]
    if init_mesh is not None:
        args += ["--init", str(init_mesh)]
    elif sft.init in INIT_OPTIONS:
        args += ["--init", INIT_OPTIONS[sft.init]]
    args += ["--effects", sft.effects.lower()]
    if sft.lighting in LIGHTING_OPTIONS:
        args += ["--lighting", LIGHTING_OPTIONS[sft.lighting]]
    elif sft.env_path:
        args += ["--env", str(abspath(sft.env_path)), "--env-strength", f"{sft.env_strength:g}",
                 "--env-rotation", f"{sft.env_rotation:g}"]
        args += ["--map-calibrated"] if sft.map_calibrated else []
    return args


def initial_object(context):
    """The mesh object Initialisation = Blender Object starts from: the chosen one, else the active one."""
    sft = context.scene.sft
    obj = sft.init_object or context.active_object
    require(obj is not None and obj.type == "MESH" and obj.name != scene_mesh.OBJECT_NAME, None,
            "no mesh object to start from", "choose one under Initialisation, or select a mesh object")
    return obj


def resume_args(run: Path) -> list[str]:
    """The command line that continues ``run``: the one recorded in RUN/command.json
    (docs/protocol.md) with ``--resume`` instead of ``--overwrite``."""
    require((run / "state" / "state.json").is_file(), run, "nothing to resume (no saved state)",
            "start a new reconstruction")
    require(not (run / "report.json").is_file(), run, "the run has already finished", "start a new reconstruction")
    try:
        argv = json.loads((run / "command.json").read_text())["argv"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise AddonInputError(run / "command.json", "cannot read the run's command line",
                              "resume it from a terminal: python -m backend reconstruct CAPTURE --out RUN "
                              "--resume with its options") from err
    return [a for a in argv if a != "--overwrite"] + ["--resume"]


def resumable(run_dir: str) -> bool:
    """Whether Resume can continue ``run_dir`` (the checks of :func:`resume_args`)."""
    if not run_dir:
        return False
    try:
        resume_args(abspath(run_dir))
    except AddonInputError:
        return False
    return True


EXCLUDES = ("reconstruct", "plan", "solve")  # a run does not start while the capture is measured or solved


def _poll_reconstruct(cls, context) -> bool:
    if not idle(cls, *EXCLUDES):
        return False
    sft = context.scene.sft
    if not sft.capture_dir:
        cls.poll_message_set("import a video and solve its cameras, or import cameras, first")
        return False
    if not capture_state.facts(context.scene).has_capture_json:  # poll runs on every redraw: no file reads
        cls.poll_message_set("the capture has no cameras yet: Solve Cameras or Import Cameras")
        return False
    return has_backend(cls, context)


class _ReconstructModal(JobModal):
    """What Reconstruct and Resume share: the job, the object it streams into, the report."""

    job_kind = "reconstruct"

    object_name: StringProperty(name="Object", default=scene_mesh.OBJECT_NAME,
                                description="Object that shows the evolving mesh")

    def launch(self, context, args: list[str], run: Path) -> jobs.ReconstructJob:
        python = backend_python(context)
        try:
            return jobs.ReconstructJob(python, args, run, self.object_name)
        except OSError as err:
            raise AddonInputError(python, f"cannot start the backend ({err.strerror})",
                                  "choose the backend Python in the add-on preferences") from err

    def finish(self, context, job: jobs.ReconstructJob):
        state = job.state
        changed = job.applied is not None
        if changed:
            context.scene.sft.run_dir = str(job.run_dir)
        if state.status == progress.DONE:
            metrics = state.done.get("metrics") or {}
            shown = ", ".join(f"{k} {v:.4g}" for k, v in metrics.items() if isinstance(v, (int, float)))
            lit = _load_estimated_lighting(context, job.run_dir)
            self.report({"INFO"}, f"reconstruction done in {progress.format_duration(state.elapsed())}"
                                  + (f": {shown}" if shown else "") + lit)
        elif state.status == progress.CANCELLED:
            self.report({"WARNING"}, "reconstruction cancelled; the last snapshot is kept (Resume continues it)"
                        if changed else "reconstruction cancelled before its first snapshot")
        else:
            self.report({"ERROR"}, f"reconstruction failed: {state.message}")
        return {"FINISHED"} if changed else {"CANCELLED"}


def _fitted_frame(run_dir) -> str | None:
    """The frame of the run's fitted map (report.json ``lighting.frame``: world, camera or
    world+camera; what an Auto run chose), None without one."""
    try:
        lighting = json.loads((Path(run_dir) / "report.json").read_text()).get("lighting") or {}
    except (OSError, ValueError, AttributeError):
        return None
    return lighting.get("frame") if isinstance(lighting, dict) else None


def _load_estimated_lighting(context, run_dir) -> str:
    """The run's estimated environment (``--lighting estimate``) into the World; a note for the report.
    A map fixed to the camera (``rig``) has no place in a World: it stays in the run folder."""
    frame = _fitted_frame(run_dir) or {"RIG": "camera", "WORLD_RIG": "world+camera"}.get(
        getattr(context.scene.sft, "lighting", ""))
    if frame == "camera":
        return "; lighting fitted on the camera rig (environment.exr in the run folder; the World is unchanged)"
    rig_part = " (its world-fixed map; the camera-fixed one is environment_rig.exr)" if frame == "world+camera" else ""
    try:
        return ("; World lit by the estimated environment" + rig_part
                if world.load_estimated_environment(context.scene, run_dir) else "")
    except AddonInputError as err:
        return f"; estimated environment not loaded ({err})"


class SFT_OT_reconstruct(_ReconstructModal, bpy.types.Operator):
    """Reconstruct shape and material in a background process; the mesh updates live.
    Cancel (or Esc over the sidebar) stops it cleanly and keeps the last snapshot"""

    bl_idname = "sft.reconstruct"
    bl_label = "Reconstruct"
    bl_options = {"REGISTER", "UNDO"}

    capture_dir: StringProperty(name="Capture", subtype="DIR_PATH", default="",
                                description="Capture folder (empty: the scene's)")
    run_dir: StringProperty(name="Run Folder", subtype="DIR_PATH", default="",
                            description="Output folder (empty: <capture>/runs/<date-time>)")

    @classmethod
    def poll(cls, context):
        return _poll_reconstruct(cls, context)

    def start(self, context) -> jobs.Job:
        capture = capture_dir(context, self.capture_dir)
        require(interpreter.has_command("reconstruct"), None,
                "the backend beside the add-on has no 'reconstruct' command",
                "update the add-on to a version whose backend includes it")
        sft = context.scene.sft
        run = abspath(self.run_dir) if self.run_dir else capture / "runs" / time.strftime("%Y%m%d-%H%M%S")
        require(not (run.is_dir() and any(run.iterdir())), run, "run folder is not empty",
                "choose a new run folder")
        require((capture / "capture.json").is_file(), capture, "the capture has no cameras yet",
                "solve the cameras (Solve Cameras) or import them first")
        init_mesh = None
        if sft.init == "OBJECT":
            obj = initial_object(context)
            init_mesh = capture / "initial" / f"{bpy.path.clean_name(obj.name)}.ply"
            faces = scene_mesh.export_object_mesh(context, obj, init_mesh)
            require(faces >= 4, None, f"object '{obj.name}' has {faces} faces", "choose a closed mesh object")
        preset = None if sft.preset == "auto" else sft.preset
        args = reconstruct_args(capture, run, preset, sft.extra_args, method_args(sft, init_mesh))
        return self.launch(context, args, run)


class SFT_OT_reconstruct_resume(_ReconstructModal, bpy.types.Operator):
    """Continue an unfinished reconstruction (cancelled or crashed) from its last snapshot,
    with the options it started with"""

    bl_idname = "sft.reconstruct_resume"
    bl_label = "Resume"
    bl_options = {"REGISTER", "UNDO"}

    run_dir: StringProperty(name="Run Folder", subtype="DIR_PATH", default="",
                            description="Run folder to continue (empty: the scene's last run)")

    @classmethod
    def poll(cls, context):
        return idle(cls, *EXCLUDES)

    def start(self, context) -> jobs.Job:
        chosen = self.run_dir or context.scene.sft.run_dir
        require(bool(chosen), None, "no run folder to resume", "reconstruct first, or give the run folder")
        run = abspath(chosen)
        return self.launch(context, resume_args(run), run)


class SFT_OT_reconstruct_cancel(CancelJob, bpy.types.Operator):
    """Stop the running reconstruction cleanly (the last snapshot stays in the scene and on disk)"""

    bl_idname = "sft.reconstruct_cancel"
    bl_label = "Cancel"
    job_kind = "reconstruct"


CLASSES = (SFT_OT_reconstruct, SFT_OT_reconstruct_resume, SFT_OT_reconstruct_cancel)
