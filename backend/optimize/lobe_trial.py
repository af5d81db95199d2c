"""The specular lobe on trial: a lobe that an effects re-check turns on in the middle of a run
is kept only if views left out of its fit render at least as well with it.

The effects decision turns the lobe on when the frames are brighter than the diffuse model
predicts where a highlight would be (``render.effects``). Under lighting fitted with the
material, most of all a map on the camera rig where every highlight faces the camera, broad
frontal shading that the map does not give yet reads the same way, and the ratio sits near
its threshold and flips from one re-check to the next. A lobe always fits the views it is
fitted to a little better (it adds a view-dependent term); what it must not do is render
other views worse.

So when the lobe turns on, every ``LEAVE_OUT``-th view is left out (when that leaves at least
two, else none): the material and a fitted lighting are saved with their loss L_before on
the left-out views (``Appearance.full_loss``); the lobe's constants and the next material
cycle are fitted on the other views (``fitting``); then, with the loss L_after on the
left-out views, the lobe stays when

    L_after <= L_before

(the cycle on the refined surface, lobe included, must not lose the views it did not see),
and otherwise the saved material and lighting come back, the lobe is off for the rest of the
run, and later re-checks leave it off (``refused``). Without views to leave out the test is
on all views. A lobe present from the first decision is not on trial: the constant stage fits
it from the start."""

from __future__ import annotations

from ..material.schedule import restore_values, saved_values
from .relight import lighting_values, put_lighting

LEAVE_OUT = 4  # every 4th view is left out of the trial's fits, to judge it on


class LobeTrial:
    """One run's lobe trials: ``start`` when the lobe turns on mid-run, ``judge`` after the
    next material cycle."""

    def __init__(self):
        self.saved = None  # (material values, lighting values or None, L_before, reason) while on trial
        self.views = None  # the views it is judged on: left out of its fits (all views when none are)
        self.left_out: set[str] = set()
        self.refused: dict | None = None  # the record of a refused lobe: off for the rest of the run
        self.records: list[dict] = []  # for report.json (effects.lobe_trials)

    @property
    def pending(self) -> bool:
        return self.saved is not None

    def start(self, appearance, mesh, material, views, reason: str) -> None:
        """Save the material and lighting before the lobe restarts, with their loss on the
        views left out of the trial's fits."""
        lighting = appearance.lighting
        ids = list(range(LEAVE_OUT // 2, len(views), LEAVE_OUT)) if len(views) >= 2 * LEAVE_OUT else []
        self.left_out = {views[i].name for i in ids}
        views = [views[i] for i in ids] or views
        before = appearance.full_loss(mesh, material, views)
        self.saved = (saved_values(material), None if lighting is None else lighting_values(lighting), before, reason)
        self.views = views

    def fitting(self, views):
        """The views a material fit uses: all of them, but for those a pending trial left out."""
        return [v for v in views if v.name not in self.left_out] if self.saved is not None else views

    def drop(self) -> None:
        """Forget a trial that something else will judge (the relight restarts every channel)."""
        self.saved, self.left_out = None, set()

    def judge(self, appearance, mesh, material) -> dict | None:
        """Keep the lobe or put the saved material and lighting back (module docstring);
        returns the record, or None when no trial is waiting."""
        if self.saved is None:
            return None
        material_values, light, before, reason = self.saved
        self.saved, self.left_out = None, set()
        after = appearance.full_loss(mesh, material, self.views)
        kept = bool(after <= before)
        if not kept:
            restore_values(material, material_values)
            material.disable("specular")
            if light is not None:
                put_lighting(appearance.lighting, light)
                appearance.capture.environment = appearance.lighting.environment()
        record = {"turned_on": reason, "judged_on": [v.name for v in self.views], "loss_before": round(before, 8),
                  "loss_after": round(after, 8), "kept": kept}
        self.records.append(record)
        if not kept:
            self.refused = record
        return record
