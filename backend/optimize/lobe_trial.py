"""The specular lobe on trial: a lobe that an effects re-check turns on in the middle of a run
is kept only if the views render at least as well with it.

The effects decision turns the lobe on when the frames are brighter than the diffuse model
predicts where a highlight would be (``render.effects``). Under lighting fitted with the
material, most of all a map on the camera rig where every highlight faces the camera, broad
frontal shading that the map does not give yet reads the same way; the lobe then restarts,
the diffuse stage that follows drops the pixels it claims as highlights, and the views render
worse than before it, with nothing that undoes it (the ratio sits near its threshold and
flips from one re-check to the next).

So the material and a fitted lighting are saved when the lobe turns on, with their full-view
loss L_before (``Appearance.full_loss``), and the first material cycle after it is judged:
with its full-view loss L_after, the lobe stays when

    L_after <= L_before

(the cycle with the lobe must not lose the views it fits), and otherwise the saved material
and lighting come back, the lobe is off for the rest of the run, and later re-checks leave
it off (``refused``). A lobe present from the first decision is not on trial: the constant
stage fits it from the start."""

from __future__ import annotations

from ..material.schedule import restore_values, saved_values
from .relight import lighting_values, put_lighting


class LobeTrial:
    """One run's lobe trials: ``start`` when the lobe turns on mid-run, ``judge`` after the
    next material cycle."""

    def __init__(self):
        self.saved = None  # (material values, lighting values or None, L_before, reason) while on trial
        self.views = None  # the views it is judged on (those it started on)
        self.refused: dict | None = None  # the record of a refused lobe: off for the rest of the run
        self.records: list[dict] = []  # for report.json (effects.lobe_trials)

    @property
    def pending(self) -> bool:
        return self.saved is not None

    def start(self, appearance, mesh, material, views, reason: str) -> None:
        """Save the material and lighting before the lobe restarts, with their loss."""
        lighting = appearance.lighting
        before = appearance.full_loss(mesh, material, views)
        self.saved = (saved_values(material), None if lighting is None else lighting_values(lighting), before, reason)
        self.views = views

    def drop(self) -> None:
        """Forget a trial that something else will judge (the relight restarts every channel)."""
        self.saved = None

    def judge(self, appearance, mesh, material) -> dict | None:
        """Keep the lobe or put the saved material and lighting back (module docstring);
        returns the record, or None when no trial is waiting."""
        if self.saved is None:
            return None
        material_values, light, before, reason = self.saved
        self.saved = None
        after = appearance.full_loss(mesh, material, self.views)
        kept = bool(after <= before)
        if not kept:
            restore_values(material, material_values)
            material.disable("specular")
            if light is not None:
                put_lighting(appearance.lighting, light)
                appearance.capture.environment = appearance.lighting.environment()
        record = {"turned_on": reason, "loss_before": round(before, 8), "loss_after": round(after, 8), "kept": kept}
        self.records.append(record)
        if not kept:
            self.refused = record
        return record
