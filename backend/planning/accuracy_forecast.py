"""Each preset's held-out PSNR on *this* capture, before the run: a probe's held-out PSNR
on the initial mesh plus the preset's calibrated gain (the model: ``probe``)."""

from __future__ import annotations

import dataclasses
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from ..geometry.init import initial_mesh
from ..optimize.appearance import Appearance
from ..optimize.views import ViewSet
from . import tracking
from .presets import lighting_kind

SPREAD_FLOOR_DB = 1.0  # a run's held-out PSNR moves by up to about this much run to run: no narrower promise
PROBE_CYCLES = 8  # most material cycles the probe runs (the constant stage ends sooner: MaterialSchedule)
GAINS_FILE = Path(__file__).resolve().parents[1] / "forecast.json"  # written by ``bench plan --calibrate``


def probe(capture, config, held=None, mesh=None) -> dict | None:
    """The probe's held-out PSNR on ``capture``, or None when nothing can be held out or the
    material is not the staged one (the gains are calibrated with it). ``config``: the probe's
    settings (``job.probe_config``); ``held``: the views (``tracking.HeldOut``) a run already
    holds out of ``capture`` (``--track-accuracy``), else the probe holds out the same ones
    itself. The initial mesh is made as the run makes it, from the fitted views only (``mesh``:
    the run's own, when it was made so with the probe's settings). Returns
    {"psnr", "seconds", "views", "source", "cycles", "faces", "size" (the scored images' long
    side, px), "lighting_kind"}.

    How well a run will render views it never fitted depends on the capture more than on the
    preset: its textures, its noise, how far the visual hull is from the object. One calibration
    scene cannot know that (the dragon's held-out PSNR says nothing about a textured teacup), so
    the prediction starts from a measurement on the capture itself:

        probe            = held-out PSNR of the run's initial mesh with its first material
                           cycles fitted (the constant stage, then one diffuse cycle, at the
                           coarse size, under the run's lighting: captured, or estimated / flash
                           fitted with it as the run fits it)
        predicted(preset) = probe + gain(preset)

    ``probe`` measures what the capture's appearance allows on the starting shape; ``gain`` is
    what the preset's geometry levels, finer textures and specular stage add on top of that,
    calibrated as the median over captures that are not used to test the prediction
    (``GAINS_FILE``, with the largest distance from that median as the prediction's spread;
    ``bench plan`` compares predicted and measured on others). The gain holds at the image sizes
    it was calibrated at: a probe scored at a finer size than every calibration capture's starts
    further below what the run's finer levels reach (the hull's error and a coarse texture show
    more), so such a prediction is marked ``finer`` (:func:`extrapolated`) and shown as a floor,
    "21+ dB", without a spread. Two refinements are recorded in
    the file and not used, because each did worse on held-out captures it had not seen
    (docs/results.md): a median per kind of lighting (an environment map, or
    lights fixed to the cameras), and a line in the probe's PSNR (``fit_line``).

    Held-out views are those ``--track-accuracy`` scores (``tracking.split``: the capture's
    ground-truth held-out views, else every ``held_out_every``-th view, left out of the probe's
    fit), rendered as the tracker renders them, so that the prediction and the run's
    ``accuracy_time`` measure the same thing. The probe runs on copies: the run's material,
    lighting and capture are not touched.
    """
    if config.material != "staged":
        return None
    start = time.perf_counter()
    config = dataclasses.replace(config, track_accuracy=True)
    if held is None or held.capture is None:
        mesh = None  # carved from every view: the probe's must not see the held-out ones
        capture, held = tracking.split(dataclasses.replace(capture), config)
        if held.capture is None:
            return None
    fit = dataclasses.replace(capture)  # the lighting fit sets its environment on this copy only
    if mesh is None:
        mesh, _ = initial_mesh(fit, config.init, config.initial_faces)
    appearance = Appearance(fit, config, emit=lambda *a, **k: {})
    with tempfile.TemporaryDirectory(prefix="sft-probe-") as folder:
        appearance.start_lighting(Path(folder))
        views = ViewSet(fit, config.max_size).at(config.coarse_size)
        material = appearance.initial_material(mesh, views)
        appearance.light_first(mesh, material, views)
        cycles = 0
        while cycles < PROBE_CYCLES and appearance.driver.stage == "constant":
            appearance.material_cycle(mesh, material, views, level=0)
            cycles += 1
        if appearance.driver.stage == "diffuse":
            appearance.material_cycle(mesh, material, views, level=0)
            cycles += 1
        tracker = tracking.AccuracyTracker(held, config)
        size = max((max(v.camera.width, v.camera.height) for v in tracker.views()), default=None)
        point = tracker.score(mesh, material, appearance.lighting, level=0, phase="probe", why="probe",
                              validation_loss=None, folder=Path(folder))
    return {"psnr": point["psnr"], "seconds": round(time.perf_counter() - start, 2), "views": point["views"],
            "source": held.source, "cycles": cycles, "faces": mesh.n_faces, "size": size,
            "lighting_kind": lighting_kind(capture, config.lighting)}


def load_gains(path: Path = GAINS_FILE) -> dict:
    """{preset: {"gain_db", ...}} from the calibration file, {} when absent or unreadable."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    presets = doc.get("presets") if isinstance(doc, dict) else None
    return {k: v for k, v in (presets or {}).items() if isinstance(v, dict) and isinstance(v.get("gain_db"), (int, float))}


def fit_line(pairs: list[tuple[float, float]]) -> dict | None:
    """The gain as a line in the probe's PSNR, by least squares over (probe, gain) pairs:
    {"intercept", "slope", "probe_range" (the probes it was fitted over), "spread_db" (its
    largest residual)}; None with fewer than three pairs or probes that do not differ."""
    if len(pairs) < 3 or len({round(p, 6) for p, _ in pairs}) < 2:
        return None
    probes, gains = (np.array(x, np.float64) for x in zip(*pairs))
    slope, intercept = np.polyfit(probes, gains, 1)
    residual = gains - (intercept + slope * probes)
    return {"intercept": round(float(intercept), 3), "slope": round(float(slope), 4),
            "probe_range": [round(float(probes.min()), 2), round(float(probes.max()), 2)],
            "spread_db": round(float(np.abs(residual).max()), 2)}


def gain(gains: dict, preset: str) -> tuple[float, float | None] | None:
    """(gain, spread) in dB of ``preset``: the median gain, the spread at least
    ``SPREAD_FLOOR_DB``; None when the preset has no calibrated gain. The file's ``line`` and
    ``kinds`` are records, not used (see ``probe``)."""
    entry = gains.get(preset)
    if not entry:
        return None
    spread = entry.get("spread_db")
    return float(entry["gain_db"]), None if spread is None else max(float(spread), SPREAD_FLOOR_DB)


def calibrated_sizes(gains: dict) -> tuple[int, int] | None:
    """The smallest and largest long side (px) at which the calibration captures' probes were
    scored, over every preset's entry; None when the file records none."""
    sizes = [int(c["probe_size"]) for entry in gains.values() for c in (entry.get("captures") or {}).values()
             if isinstance(c, dict) and isinstance(c.get("probe_size"), (int, float))]
    return (min(sizes), max(sizes)) if sizes else None


def extrapolated(probed: dict | None, gains: dict | None = None) -> str | None:
    """'finer' (or 'coarser') when the probe scored larger (smaller) images than every
    calibration capture's, else None (also when either size is not known)."""
    gains = load_gains() if gains is None else gains
    known = calibrated_sizes(gains)
    size = None if probed is None else probed.get("size")
    if known is None or not isinstance(size, (int, float)):
        return None
    return "finer" if size > known[1] else "coarser" if size < known[0] else None


def predicted_psnr(probed: dict | None, preset: str, gains: dict | None = None) -> float | None:
    """The held-out PSNR ``preset`` is expected to reach: the probe's plus the preset's gain
    (None without a probe or a calibrated gain)."""
    gains = load_gains() if gains is None else gains
    found = None if probed is None else gain(gains, preset)
    return None if found is None else round(probed["psnr"] + found[0], 2)
