"""What the reconstruction loop needs to run materials, in a few calls.

    driver = MaterialDriver(capture, n_materials=1)         # material masks checked (InputError)
    material = driver.material(mesh, cameras, images, masks) # labels voted, neutral grey start
    ... after each geometry level, with the level's renderer and views:
    driver.cycle(renderer, images, masks, material, emit)    # one stage of the schedule
    driver.on_remesh(mesh, material, cameras, reset=False)   # after a re-mesh (labels re-voted)
    driver.finalise()                                        # geometry converged: last, longer stages
    driver.restart(material, 3)                              # ... from grey, constants first (a relight)
    driver.schedule.refine() / .skip_to()                      # the schedule's other moves
    driver.settle(renderer, images, masks, material)         # the end: keep the specular texture?
    driver.state() / driver.restore(state, images, masks)   # the schedule's position, for --resume

``driver.done`` tells when the material schedule has finished (the loss stopped improving
in the last stage)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from ..capture.model import Camera, Capture
from ..geometry.mesh import Mesh
from .factory import create
from .labels import FaceLabels, choose_material_count, face_labels, load_material_labels
from .model import MeshColorMaterial
from .schedule import MaterialSchedule, run_cycle
from .stages import FitResult, FitSettings, check_specular_texture, check_views, fit_lobe


@dataclass
class MaterialDriver:
    capture: Capture
    # materials to find by clustering when the capture has no material masks; "auto": as many
    # as the colours show (choose_material_count), resolved on the first material()
    n_materials: int | str = 1
    resolution: int = 4  # mesh-color resolution r
    settings: FitSettings = field(default_factory=FitSettings)
    schedule: MaterialSchedule = field(default_factory=MaterialSchedule)
    labels: FaceLabels | None = None
    results: list[FitResult] = field(default_factory=list)
    specular_check: dict | None = None  # what settle() found

    def __post_init__(self):
        self.label_images = load_material_labels(self.capture)  # bad masks fail before any work
        self._images = self._masks = None

    @property
    def done(self) -> bool:
        return self.schedule.stage == "done"

    @property
    def stage(self) -> str:
        """The stage the next cycle runs (MaterialSchedule.STAGES)."""
        return self.schedule.stage

    def material(self, mesh: Mesh, cameras: list[Camera], images: list[np.ndarray],
                 masks: list[np.ndarray] | None) -> MeshColorMaterial:
        """A neutral grey material on ``mesh`` with per-face labels from the masks (or colours)."""
        self._images, self._masks = images, masks
        if self.n_materials == "auto":
            self.n_materials = 1 if self.label_images is not None else choose_material_count(images, masks)
        self.labels = face_labels(mesh, cameras, self.label_images, images, masks, self.n_materials)
        return create("staged", mesh, self.resolution, self.labels.labels, self.labels.n_materials)

    def relabel(self, mesh: Mesh, material: MeshColorMaterial, cameras: list[Camera]) -> None:
        """Vote the labels again on the current geometry (when several materials exist)."""
        if self.label_images is None and self.n_materials <= 1:
            return
        self.labels = face_labels(mesh, cameras, self.label_images, self._images, self._masks, self.n_materials)
        material.set_labels(self.labels.labels, self.labels.n_materials)

    def cycle(self, renderer, images, masks, material: MeshColorMaterial, emit=None, lighting=None) -> FitResult:
        """Run the schedule's current stage once on ``renderer`` (built with ``material.field``);
        ``lighting``, an estimated environment, is fitted with it."""
        result = run_cycle(self.schedule, renderer, images, masks, material, self.settings, emit, lighting=lighting)
        self.results.append(result)
        return result

    def lobe_on(self, renderer, images, masks, material: MeshColorMaterial, emit=None) -> FitResult | None:
        """The specular lobe was turned on: fit its constants now, unless the constant stage is
        about to (its textured stages then start from them)."""
        if self.schedule.stage == "constant":
            return None
        result = fit_lobe(renderer, images, masks, material, self.settings, emit)
        self.results.append(result)
        return result

    def finalise(self, last: str = "specular", iterations_scale: int = 4) -> None:
        """Geometry has converged: longer textured stages to the end (MaterialSchedule.finalise)."""
        if not self.schedule.final:
            self.schedule.finalise(last=last)
            self.settings = replace(self.settings, iterations=self.settings.iterations * iterations_scale)

    def restart(self, material: MeshColorMaterial, constant_cycles: int) -> None:
        """The material back to neutral grey constants and the schedule to its constant stage
        (MaterialSchedule.restart), keeping the final stages' length."""
        material.reset()
        self.schedule.restart(constant_cycles)

    def settle(self, renderer, images, masks, material: MeshColorMaterial) -> dict | None:
        """The run's last material step: a specular texture stays only if it renders the views
        its stage left out better than its mean (``check_specular_texture``)."""
        views = check_views(len(images), self.settings.check_every)
        if not views or material.channels["specular"].kind != "colors":
            return None
        self.specular_check = check_specular_texture(renderer, images, masks, material, views)
        return self.specular_check

    def on_remesh(self, mesh: Mesh, material: MeshColorMaterial, cameras: list[Camera],
                  reset: bool = True) -> None:
        """Call after ``material.on_remesh(mesh, ..., reset)``: labels re-voted; the schedule
        restarts from its constant stage when the material was ``reset`` to grey, else goes on
        as after a simplification (the material resampled, its stage kept)."""
        self.relabel(mesh, material, cameras)
        if reset:
            self.schedule.on_remesh()

    def state(self) -> dict:
        """The schedule's position and the stage length, JSON-able (for --resume)."""
        schedule = asdict(self.schedule)
        schedule["best"] = schedule["best"] if math.isfinite(schedule["best"]) else None
        return {"schedule": schedule, "iterations": self.settings.iterations}

    def restore(self, state: dict | None, images: list[np.ndarray], masks: list[np.ndarray] | None) -> None:
        """Continue a resumed run where ``state`` (from ``state()``) left the schedule; the
        material itself comes from its own file. ``images``/``masks`` as for ``material()``."""
        self._images, self._masks = images, masks
        if state:
            best = state["schedule"]["best"]
            self.schedule = MaterialSchedule(**dict(state["schedule"], best=math.inf if best is None else best))
            self.settings = replace(self.settings, iterations=int(state["iterations"]))

    def report(self) -> dict:
        out = {"stages": [{"stage": r.stage, "iterations": len(r.losses), "loss": r.loss,
                           "seconds": round(r.seconds, 2), "highlight_share": r.highlight_share}
                          for r in self.results],
               "schedule": self.schedule.history, "specular_check": self.specular_check}
        if self.labels is not None:
            out["labels"] = {"materials": self.labels.material_ids, "disagreement": self.labels.disagreement,
                             "votes": self.labels.votes, "unseen_faces": self.labels.unseen_faces}
        return out
