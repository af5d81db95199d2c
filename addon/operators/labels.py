"""Preview Material Labels: the per-material regions Reconstruct clusters from the frames'
colours (``python -m backend labels``), shown as a colour overlay on the frames before a run.

The backend writes one overlay PNG per frame into the capture's ``labels_preview/`` (replaced
whole, so a failed run leaves the last one); each frame's camera shows its overlay as the
background image instead of the frame, and Show Labels (in the Reconstruct panel) switches
between the two. The overlay of the preview frame is also loaded as an image, shown in an open
Image editor."""

from pathlib import Path

import bpy
from bpy.props import IntProperty

from .. import jobs, preview
from ..io.errors import require
from ..preferences import backend_python
from ..scene_cameras import COLLECTION, show_labels
from .common import capture_dir, has_backend, idle
from .modal import JobModal

PREVIEW_FOLDER = "labels_preview"
IMAGE_NAME = "SfT Material Labels"


class SFT_OT_preview_labels(JobModal, bpy.types.Operator):
    """Cluster the object's colours into the material regions Reconstruct would use and show
    them as a colour overlay on the frames (each frame camera's background; Show Labels switches
    back to the frames)"""

    bl_idname = "sft.preview_labels"
    bl_label = "Preview Material Labels"

    job_kind = "labels"

    materials: IntProperty(name="Materials", default=0, min=0, max=8,
                           description="Materials to cluster the colours into; 0: as many as the colours show")

    @classmethod
    def poll(cls, context):
        if not idle(cls, cls.job_kind, "solve", "video", "masks"):  # they rewrite the frames and masks
            return False
        return has_backend(cls, context)

    def start(self, context) -> jobs.Job:
        capture = capture_dir(context)
        require((capture / "capture.json").is_file(), capture, "no solved capture (capture.json)",
                "solve the cameras first (Solve Cameras), or import them (Import Cameras)")
        self.folder = capture / PREVIEW_FOLDER
        args = ["labels", "--capture", str(capture), "--out", str(self.folder),
                "--materials", str(self.materials) if self.materials else "auto"]
        return jobs.Job(backend_python(context), args, None, kind=self.job_kind)

    def finish(self, context, job: jobs.Job):
        if job.state.status != "done":
            self.report({"ERROR"}, f"material labels {job.state.status}: {job.state.message}")
            return {"CANCELLED"}
        done = job.state.done
        collection = bpy.data.collections.get(COLLECTION)
        for obj in collection.objects if collection else ():
            overlay = self.folder / f"{obj.get('sft_frame', '')}.png"
            if overlay.is_file():
                obj["sft_labels"] = str(overlay)
        context.scene.sft.show_labels = True
        shown_on = show_labels(context.scene, True)  # also when Show Labels was on already
        overlays = sorted(self.folder.glob("*.png"))
        shown = overlays[min(context.scene.sft.preview_frame, len(overlays) - 1)]
        image = preview.show(shown, IMAGE_NAME)
        for area in context.screen.areas if context.screen else ():
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = image
        shares = ", ".join(f"{100 * s:.0f} %" for s in done.get("shares", []))
        self.report({"INFO"}, f"{done.get('materials')} material labels ({done.get('source')}: {shares}) "
                              f"on {done.get('frames')} frames in {self.folder} ({shown_on} cameras show them)")
        return {"FINISHED"}


CLASSES = (SFT_OT_preview_labels,)
