"""The ``reconstruct`` command's application layer: request (its parsed options) → checked
config (``config_from_args``) → the preset event and plan → ``optimize.run.reconstruct``, with
the held-out tracker and the time-left estimate it is given (``run``)."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

from .. import interrupt, variant
from ..capture.format import FILENAME
from ..capture.load import load_capture
from ..errors import InputError, require
from ..events import Emitter, read_log
from ..geometry.init import cached_initial_mesh
from ..lighting.modes import resolve_lighting
from ..video.inputs import check_inputs, write_capture
from ..optimize.appearance import Appearance
from ..optimize.config import STAGED_FACE_GROWTH, ReconstructConfig
from ..optimize.run import reconstruct
from ..optimize.run_folder import RunFolder
from . import lighting_choice, tracking
from .accuracy_forecast import probe
from .presets import DEFAULT, PRESETS, calibrated, calibration_scene, lighting_kind, preset_for_budget
from .remaining import Remaining, resumed
from .time_plan import capture_plan, level_limit, make_plan

OVERRIDES = ("init", "material", "effects", "initial_faces", "iterations", "seed", "max_size", "coarse_size", "views_per_step",
             "integrator", "max_depth", "spp", "primal_spp", "sppp", "remesh", "max_levels", "level_iterations", "step", "lambda_",
             "face_growth", "track_metrics", "track_accuracy", "held_out_every", "texture_stage", "texture_size",
             "exposure", "map_calibrated", "n_materials", "refine_cameras")
VIDEO_SUFFIXES = {".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mts", ".mpg", ".mpeg", ".ogv"}
DEFAULT_MATERIAL = "staged"
MATERIAL_ALIASES = {"constant": "auto", "full": "staged"}
SETTINGS_VARIABLE = "SFT_RECONSTRUCT_SETTINGS"
PATH_OPTIONS = ("--out", "--masks", "--env", "--init")


def choose_preset(args) -> str:
    """The preset asked for; else, with a time budget, the calibrated one that fits it (by the
    calibration of ``args.lighting_kind``, set once the capture's lighting is known)."""
    if args.preset:
        return args.preset
    if args.time_budget is None:
        return DEFAULT
    return preset_for_budget(args.time_budget, kind=getattr(args, "lighting_kind", None) or "point")


def config_from_args(args) -> ReconstructConfig:
    """Defaults, then the preset, then the options given."""
    for name in ("max_size", "coarse_size", "views_per_step", "initial_faces", "spp", "primal_spp", "sppp",
                 "max_levels", "iterations",
                 "time_budget", "max_depth", "level_iterations", "step", "lambda_", "texture_size"):
        value = getattr(args, name)
        flag = "--smoothing" if name == "lambda_" else "--" + name.replace("_", "-")
        require(value is None or value > 0, None, f"{flag} must be positive (got {value})", f"give {flag} a value above 0")
    every = args.held_out_every
    require(every is None or every >= 2, None, f"--held-out-every must be 2 or more (got {every})",
            "give e.g. --held-out-every 8 (every 8th view held out)")
    growth = args.face_growth
    require(growth is None or (math.isfinite(growth) and growth > 1), None,
            f"--face-growth must be above 1 (got {growth})", "give e.g. --face-growth 1.5")
    materials = getattr(args, "n_materials", None)
    materials = None if materials is None else str(materials)
    require(materials is None or materials == "auto" or (materials.isdigit() and 1 <= int(materials) <= 16), None,
            f"--materials {materials} is not a count from 1 to 16 nor auto", "give e.g. --materials 3 or --materials auto")
    values = dict(PRESETS[choose_preset(args)])
    values.update(settings_from_environment())
    values.update({k: getattr(args, k) for k in OVERRIDES if getattr(args, k, None) not in (None, False)})
    if materials is not None:
        values["n_materials"] = materials if materials == "auto" else int(materials)
    values["material"] = MATERIAL_ALIASES.get(values.get("material"), values.get("material")) or DEFAULT_MATERIAL
    if args.time_budget is not None:
        values["time_budget_s"] = 60.0 * args.time_budget
    if getattr(args, "known_albedo", None) is not None:
        values["known_albedo"] = known_albedo(args.known_albedo)
    config = ReconstructConfig(**values)
    config.coarse_size = min(config.coarse_size, config.max_size)
    if config.face_growth is None and config.material == "staged":
        config.face_growth = STAGED_FACE_GROWTH
    return config


def known_albedo(text: str) -> tuple[float, float, float]:
    """``--known-albedo R,G,B``: three linear values in (0, 1), else InputError."""
    try:
        rgb = tuple(float(x) for x in str(text).split(","))
    except ValueError:
        rgb = ()
    require(len(rgb) == 3 and all(0 < x < 1 for x in rgb), None,
            f"--known-albedo must be three linear values in (0, 1) (got {text})", "give e.g. --known-albedo 0.6,0.45,0.3")
    return rgb


def settings_from_environment() -> dict:
    """``$SFT_RECONSTRUCT_SETTINGS``: a JSON object of ReconstructConfig fields, checked."""
    text = os.environ.get(SETTINGS_VARIABLE, "").strip()
    if not text:
        return {}
    fix = f'set {SETTINGS_VARIABLE} to a JSON object such as {{"max_size": 32}}, or unset it'
    try:
        values = json.loads(text)
    except ValueError:
        raise InputError(None, f"${SETTINGS_VARIABLE} is not JSON", fix) from None
    require(isinstance(values, dict), None, f"${SETTINGS_VARIABLE} is not a JSON object", fix)
    known = set(ReconstructConfig.__dataclass_fields__)
    unknown = sorted(set(values) - known)
    require(not unknown, None, f"${SETTINGS_VARIABLE} names unknown settings: {', '.join(unknown)}", fix)
    return values


def resumed_material(run: Path) -> str | None:
    """The material a run started with (its first ``start`` event), or None when unknown."""
    start = next((e for e in read_log(Path(run) / "events.jsonl") if e.get("event") == "start"), None)
    return None if start is None else (start.get("settings") or {}).get("material")


def video_inputs(args):
    """The checked inputs of ``capture-from-video`` when PATH is a video with --masks, else None."""
    if args.masks is None:
        path = Path(args.capture)
        require(not (path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES), path,
                "a video needs its object masks", "give --masks MASKS (and the lighting with --env HDR)")
        return None
    return check_inputs(SimpleNamespace(capture=args.capture, masks=args.masks, env=args.env,
                                        env_rotation=args.env_rotation, align_lighting=args.align_lighting))


def video_capture(inputs, folder, resume: bool, emit):
    """RUN/capture written from the video inputs (kept when resuming), loaded."""
    path = folder.path / "capture"
    if not (resume and (path / FILENAME).is_file()):
        write_capture(inputs, path, emit, overwrite=True)
    return load_capture(path)


def absolute_paths(argv: list[str], args) -> list[str]:
    """``argv`` with the capture and the path options made absolute, so the recorded command
    resumes from any working folder (``--init`` only when it names an existing file)."""
    out, previous = [], None
    for token in argv:
        option, eq, value = token.partition("=")
        if eq and option in PATH_OPTIONS:
            token = f"{option}={_absolute(option, value)}"
        elif previous in PATH_OPTIONS:
            token = _absolute(previous, token)
        elif not token.startswith("-") and Path(token) == args.capture:
            token = os.path.abspath(token)
        out.append(token)
        previous = token
    return out


def _absolute(option: str, value: str) -> str:
    return value if option == "--init" and not Path(value).is_file() else os.path.abspath(value)


def run(args) -> int:
    """One ``reconstruct`` request, start to end: its exit code (0 done, 130 cancelled; bad
    input raises :class:`InputError`).

    :func:`run` takes the command's options (an ``argparse.Namespace`` or anything with the same
    attributes), checks them into a :class:`ReconstructConfig` (defaults, then the preset or the
    one that fits ``--time-budget``, then ``$SFT_RECONSTRUCT_SETTINGS``, then the options given),
    resolves the capture (a folder, or a video written to RUN/capture) and its lighting, and
    either prints ``--plan`` or runs :func:`backend.optimize.run.reconstruct` into the run
    folder, returning its exit code. Shared by the command and anything that starts a run from
    options (:func:`config_from_args` is also what tests and the presets' plan use).
    """
    from ..material.constant import parse_spec  # loads Mitsuba: only once a run starts, not on import

    started = getattr(args, "started", None) or time.perf_counter()  # the budget's clock: the command's start
    if args.resume and args.material is None:
        args.material = resumed_material(args.out)
    config = config_from_args(args)
    parse_spec(config.material)  # bad input is reported before anything is written
    video = video_inputs(args)
    capture = load_capture(args.capture) if video is None else None
    config.lighting = resolve_lighting(capture, args.lighting, args.env, args.env_strength, args.env_rotation,
                                       args.capture, video_light=video is not None and video.environment is not None)
    before = choose_preset(args)
    args.lighting_kind = ("environment" if video is not None and video.environment is not None
                          else lighting_kind(capture, config.lighting))
    if choose_preset(args) != before:  # a time budget's preset, by the capture's kind of lighting
        config = dataclasses.replace(config_from_args(args), lighting=config.lighting)
    chosen = variant.choose(args.variant)
    if capture is not None:
        Appearance.check(capture, config)
    if getattr(args, "plan", False):
        return _print_plan(args, capture, config.lighting)
    folder = RunFolder.create(args.out, resume=args.resume, overwrite=args.overwrite)
    if not args.resume and getattr(args, "argv", None):
        folder.record_command(absolute_paths(args.argv, args))
    emit = Emitter(log_path=folder.events)
    emit.start = started  # event times, like the budget, count from the command's start
    try:
        with reported(emit):
            emit("start", run=str(folder.path), capture=str(args.capture), settings=dataclasses.asdict(config))
            emit("variant", variant=chosen, llvm=os.environ.get("DRJIT_LIBLLVM_PATH"))
            if video is not None:
                capture = video_capture(video, folder, args.resume, emit)
                Appearance.check(capture, config)
            choice = initial = later = None
            if config.lighting == "auto":
                config, choice, initial, later = _choose_lighting(args, capture, config, emit, folder)
            planner, limit = _preset_event(args, emit, config, capture, folder)
            remaining = resumed(folder.events, config.time_budget_s) if args.resume else None  # its plan, phases done
            return reconstruct(capture, folder, config, emit, resume=args.resume, planner=planner,
                               tracking=tracking.start, remaining=remaining, started=started,
                               level_limit=limit, lighting_choice=choice, initial=initial,
                               lighting_probe=later).exit_code
    finally:
        emit.close()


def _choose_lighting(args, capture, config, emit, folder):
    """``--lighting auto``: (the config with the lighting the run starts under, report.json
    ``lighting_choice`` when made before the run, the run's initial mesh and its kind or None,
    the ``lighting_choice.Deferred`` that chooses after the first level or None).

    A capture that records no light is probed after the run's first level, on its mesh
    (``lighting_choice.Deferred``): the run starts under the provisional lighting and
    ``reconstruct`` switches to the winner. A capture with its own lights, or too few frames,
    is probed here, before the run, on the run's own initial mesh, which the run then starts
    from. The probe fits only what the run fits (``--track-accuracy``'s held-out views are left
    out); a time budget's preset is then chosen again for the winner's kind of lighting. A
    resumed run keeps the choice its folder's events recorded (or, when its first run stopped
    before choosing, waits for the end of its level as a new run does). A deferred choice keeps
    the preset chosen for ``auto`` (an environment: ``lighting_kind``): the run has started."""
    choice = lighting_choice.resumed(read_log(folder.events)) if args.resume else None
    if choice is not None:
        emit(lighting_choice.EVENT, **choice)
        return dataclasses.replace(config, lighting=resolve_lighting(capture, choice["winner"], source=args.capture)), \
            choice, None, None
    fits, _ = tracking.split(capture, config)  # the frames the run fits, as it splits them
    modes = lighting_choice.candidates(fits)
    if lighting_choice.deferred(fits, modes):
        later = lighting_choice.Deferred(config, modes, config.time_budget_s)
        lighting = resolve_lighting(capture, later.provisional, source=args.capture)
        return dataclasses.replace(config, lighting=lighting), None, None, later
    initial = None
    if not args.resume:
        emit("stage", stage="init", level=0, faces=0)
        initial = cached_initial_mesh(fits, config.init, config.initial_faces,
                                      warn=lambda message: emit("warning", message=message))
    choice = lighting_choice.choose(fits, config, emit, config.time_budget_s, modes=modes,
                                    mesh=None if initial is None else initial[0])
    lighting = resolve_lighting(capture, choice["winner"], source=args.capture)
    before = choose_preset(args)
    args.lighting_kind = lighting_kind(capture, lighting)
    if choose_preset(args) != before:  # a time budget's preset, by the winner's kind of lighting
        config = config_from_args(args)
    return dataclasses.replace(config, lighting=lighting), choice, initial, None


@contextmanager
def reported(emit):
    """Errors and interruptions inside become ``error`` / ``cancelled`` events, then propagate."""
    try:
        yield
    except InputError as err:
        emit("error", message=err.line())
        raise
    except KeyboardInterrupt:
        emit("cancelled", snapshot=None)
        raise
    except Exception as err:
        if interrupt.is_cancel(err):  # an interrupt a native library wrapped (backend/interrupt.py)
            emit("cancelled", snapshot=None)
            raise KeyboardInterrupt from None
        emit("error", message=f"{type(err).__name__}: {err}")
        raise


def _preset_configs(args, names) -> dict:
    """{preset: its ReconstructConfig with this command line's options}."""
    return {name: config_from_args(SimpleNamespace(**{**vars(args), "preset": name})) for name in names}


def _print_plan(args, capture, lighting: str) -> int:
    """--plan: each preset's predicted time on this capture (planning/time_plan.py), printed; no run."""
    require(capture is not None, args.capture, "--plan needs a capture folder",
            "write the capture first (capture-from-video), then plan on it")
    lighting = "estimate" if lighting == "auto" else lighting  # planned as the probe's most common winner
    probed = safe_probe(probe, capture, probe_config(args, lighting), warn=lambda m: print(f"warning: {m}", flush=True))
    plan = capture_plan(capture, _preset_configs(args, PRESETS), calibrated(kind=lighting_kind(capture, lighting)),
                        probe=probed)
    print(plan.table())
    print(f"{plan.line()} on this capture (step costs measured in {plan.costs.seconds:.1f} s)", flush=True)
    # the same as one event (docs/protocol.md) for the add-on's Plan button
    Emitter()("plan", line=plan.line(), **plan.to_json())
    return 0


def probe_config(args, lighting: str):
    """The settings of the accuracy probe (planning/accuracy_forecast.py): the default preset's with this
    command line's options, whatever preset runs, so that one probe serves every preset."""
    return dataclasses.replace(_preset_configs(args, [DEFAULT])[DEFAULT], lighting=lighting)


def safe_probe(probe, capture, config, held=None, warn=print, mesh=None):
    """``probe(capture, config, held, mesh)``, or None with a warning when it fails: a prediction
    that cannot be made must not stop the run it predicts."""
    try:
        return probe(capture, config, held, mesh)
    except (InputError, RuntimeError, ValueError) as err:
        warn(f"no predicted accuracy: the probe failed ({err})")
        return None


def _preset_note(preset: str, expected: dict, kind: str) -> str | None:
    """What the ``preset`` event warns of: no calibration for the kind, or a preset that a
    cheaper one matched on the kind's calibration scene."""
    if not expected:
        return (f"no calibration scene lit as this capture is ({kind}); the time comes from this capture's "
                "measured steps")
    if expected.get("dominated_by"):
        return (f"{preset} was no more accurate than {expected['dominated_by']} on the calibration scene lit as "
                f"this capture is ({kind}), in more time")
    return None


def _preset_event(args, emit, config, capture, folder):
    """The ``preset`` event, at once: the preset chosen and its calibrated figures; and
    (planner, level limit) for ``reconstruct``. The level limit comes from the calibration
    alone. A new run's planner, which ``reconstruct`` calls once its first level has ended
    (so that the first step comes without delay, with the effects the run decided),
    predicts this capture's time from its step costs (cached beside the capture by
    ``step_costs.cached``; measured only without a time budget: a budgeted run ends at its
    budget whatever the plan says, and the measurement would take its time from the fit for
    an estimate of the time left that changes no decision), announces it in a second
    ``preset`` event and returns the live estimate of the time left, caught up with the
    events so far. The held-out PSNR is predicted only with ``--track-accuracy`` (the probe
    decides nothing in the run: the Plan button and ``--plan`` probe)."""
    preset = choose_preset(args)
    kind = lighting_kind(capture, config.lighting)
    entries = calibrated(kind=kind)
    expected = entries.get(preset, {})

    def event(plan=None):
        # expected_*: the figures of the calibration scene lit as this capture is (point lights or
        # an environment map; null where that kind is not calibrated); predicted_*: this capture's
        # own, from its step costs (planning/time_plan.py) and its accuracy probe
        chosen = None if plan is None else plan.presets[preset]
        emit("preset", preset=preset, chosen_for_budget=args.preset is None and args.time_budget is not None,
             expected_minutes=expected.get("expected_minutes"), expected_f1=expected.get("expected_f1"),
             calibrated_on=calibration_scene(kind), lighting_kind=kind,
             predicted_minutes=None if chosen is None else round(chosen.minutes, 2),
             predicted_psnr=None if chosen is None else chosen.predicted_psnr,
             psnr_spread=None if chosen is None else chosen.psnr_spread,
             psnr_extrapolated=None if chosen is None else chosen.psnr_extrapolated,
             probe=None if plan is None else plan.probe,
             plan=None if plan is None else {**chosen.to_json(), "costs": plan.costs.to_json(),
                                             "render_settings": plan.settings},
             dominated_by=expected.get("dominated_by"), note=_preset_note(preset, expected, kind))

    event()
    if args.resume:
        return None, None

    def planner(capture, viewset, settings, material_settings, mesh, held):
        probed = None
        if config.track_accuracy:
            probing = probe_config(args, config.lighting)
            probed = safe_probe(probe, capture, probing, held, warn=lambda m: emit("warning", message=m), mesh=mesh)
        budget = config.time_budget_s
        plan = make_plan(capture, {preset: config}, settings, staged=config.material == "staged",
                         calibration=entries, viewset=viewset, material_settings=material_settings,
                         initial=mesh, probe=probed, measure=budget is None)
        if plan is None:
            return None
        event(plan)
        remaining = Remaining.from_plan(plan.presets[preset], budget)  # the time left follows it
        for e in read_log(folder.events):
            remaining.observe(str(e.get("event")), e, float(e.get("time") or 0.0))
        return remaining

    return planner, level_limit(config, expected)
