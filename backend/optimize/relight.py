"""The relight: once geometry has converged, a fitted lighting and the material go back to
their initial values and are fitted again on the final surface, kept only if they render
the views as well (the rule: ``Relight``)."""

from __future__ import annotations

import numpy as np

from ..material.schedule import restore_values, saved_values

TOLERANCE = 1.25


def _lighting_values(lighting) -> tuple[np.ndarray, int | None]:
    return np.array(lighting.latent, copy=True), getattr(lighting, "level", None)


def _put_lighting(lighting, values) -> None:
    latent, level = values
    lighting.latent = latent
    if level is not None:
        lighting.level = level


class Relight:
    """One run's relight: ``start`` it, then ``judge`` it once the final stages end.

    Fitted along with a surface that moves through its levels and re-meshes, the albedo takes up
    shading that the intermediate surfaces and lightings got wrong, and the lighting drifts to
    match it: the fitted views still match, but the split of light and albedo does not carry to
    another light. Fitted afresh on the final surface it does
    (docs/notes/2026-11-28-relight.md).

    A fresh fit can also fail where the lighting is hard to separate from the material (a map on
    the camera rig, where every view's highlights face the camera: ``Appearance.finalise`` does not
    relight one, since every fresh fit under it lost the views), so the relight is judged once
    the final stages end: with the full-view loss L (``Appearance.full_loss``, the views at full
    size) of the material and lighting before it, L_before, and after it, L_after, the relit
    ones are kept when

        L_after <= TOLERANCE x L_before

    and the earlier ones are put back otherwise. The tolerance admits the small loss a
    relight costs on the views it fits (the albedo no longer paints shading in) while refusing a
    fit that lost the views.
    """

    def __init__(self):
        self.saved = None  # (material values, lighting values, L_before) while being judged
        self.views = None  # the final views it is judged on
        self.record: dict | None = None  # for report.json lighting.relight

    def start(self, appearance, mesh, material, views) -> None:
        """Save what is there, then restart the lighting and the material."""
        lighting = appearance.lighting
        before = appearance.full_loss(mesh, material, views)
        self.saved, self.views = (saved_values(material), _lighting_values(lighting), before), views
        lighting.restart(appearance.capture)
        appearance.capture.environment = lighting.environment()
        appearance.driver.restart(material, appearance.config.light_first_cycles)

    def judge(self, appearance, mesh, material) -> dict | None:
        """Keep the relit material and lighting, or put the earlier ones back (module
        docstring); returns the record, or None when no relight is waiting. Also on a cancel
        during the relight: a half-done relight that renders the views worse is not kept."""
        if self.saved is None:
            return None
        material_values, lighting_values, before = self.saved
        self.saved = None
        after = appearance.full_loss(mesh, material, self.views)
        kept = bool(after <= TOLERANCE * before)
        if not kept:
            restore_values(material, material_values)
            _put_lighting(appearance.lighting, lighting_values)
            appearance.capture.environment = appearance.lighting.environment()
        self.record = {"loss_before": round(before, 8), "loss_after": round(after, 8), "tolerance": TOLERANCE,
                       "kept": kept}
        return self.record
