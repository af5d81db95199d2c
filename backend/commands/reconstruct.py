"""``reconstruct``: refine a mesh until path-traced renders match the capture.

Writes the run folder of docs/protocol.md: events.jsonl, snapshot.json + snapshots/,
state/ (for --resume), result.ply and report.json. Exit codes: 0 done, 1 internal error,
2 bad input, 130 cancelled (SIGTERM, SIGINT or RUN/STOP). ``reconstruct VIDEO --masks MASKS --env HDR``
first writes RUN/capture as ``capture-from-video`` does (reused by --resume).

With no options it runs the whole method: the staged mesh-color material, effects measured
on the scene, the Balanced preset (or, with --time-budget, the preset that fits it), and
``RUN/result.glb``. ``--env HDR`` (with ``--env-strength`` and ``--env-rotation``) lights
any capture with that map. ``$SFT_RECONSTRUCT_SETTINGS`` (a JSON object of settings, e.g.
``{"max_size": 32}``) applies over the preset and under the options: tests and scripted
runs shrink a run with it without changing the command line."""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path
from types import SimpleNamespace

from .. import variant
from ..errors import InputError, require
from ..events import Emitter
from ..optimize.config import STAGED_FACE_GROWTH, ReconstructConfig
from ..optimize.presets import DEFAULT, PRESETS, calibrated, load_calibration, preset_for_budget

INIT_HELP = "carve (visual hull; default with masks), sphere, box, spheres (sphere cloud), points (SfM + Poisson), or a mesh file"


def _calibration_help() -> str:
    """Each preset's calibrated time and F1 (backend/presets.json), for --help."""
    entries = calibrated()
    if not entries:
        return "Not calibrated (python -m backend bench calibrate)."
    parts = [f"{name} ~{e['expected_minutes']:.3g} min, F1@0.01 {100 * e.get('expected_f1', 0):.1f}"
             for name, e in entries.items()]
    return f"Calibrated on the dragon benchmark: {'; '.join(parts)} (backend/presets.json)."


def add_arguments(parser):
    d = ReconstructConfig()
    parser.add_argument("capture", metavar="PATH", type=Path,
                        help="capture folder (or any importable layout: transforms.json, COLMAP, IDR, Middlebury), "
                             "or a video (or folder of frames) with --masks and --env")
    parser.add_argument("--masks", metavar="MASKS", help="with a video: its object masks (folder of images or a video)")
    parser.add_argument("--env", metavar="HDR",
                        help="equirectangular HDR map of the lighting: with a video it is aligned to the frames; "
                             "with a capture folder it replaces the capture's lighting")
    parser.add_argument("--env-strength", type=float, metavar="S",
                        help="with a capture folder and --env: the map's strength (default 1)")
    from ..video.inputs import add_lighting_arguments

    add_lighting_arguments(parser)
    from ..lighting.setup import HELP as LIGHTING_HELP, MODES as LIGHTING_MODES

    parser.add_argument("--lighting", choices=LIGHTING_MODES, help=LIGHTING_HELP)
    parser.add_argument("--out", required=True, type=Path, metavar="RUN", help="run folder")
    parser.add_argument("--preset", choices=sorted(PRESETS),
                        help=f"quality preset (default {DEFAULT}; with --time-budget, the most accurate preset whose "
                             f"calibrated time fits it); the options below override it. {_calibration_help()}")
    parser.add_argument("--init", default=None, help=INIT_HELP)
    parser.add_argument("--time-budget", type=float, metavar="MINUTES",
                        help="wall-clock budget of the whole run: it stops then with the best mesh so far")
    parser.add_argument("--iterations", type=int, help="cap on optimisation steps over all levels")
    parser.add_argument("--seed", type=int, default=d.seed)
    parser.add_argument("--resume", action="store_true", help="continue the run in RUN from its last snapshot")
    parser.add_argument("--overwrite", action="store_true", help="replace the outputs of an earlier run in RUN")
    parser.add_argument("--max-size", type=int, metavar="PX", help=f"long side of the finest images ({d.max_size})")
    parser.add_argument("--coarse-size", type=int, metavar="PX",
                        help=f"long side of the first level's images ({d.coarse_size})")
    parser.add_argument("--views-per-step", type=int, metavar="K", help=f"views rendered per step ({d.views_per_step})")
    parser.add_argument("--material", default=None,
                        help="'staged' (the default: spatially varying mesh colors, fitted as constants, then "
                             "diffuse, then specular; writes RUN/result.glb), 'constant' (one material for the "
                             "whole object, estimated) or known:ALBEDO_R,G,B:SPECULAR:ROUGHNESS. A resumed run "
                             "keeps the material it started with")
    parser.add_argument("--effects", default=d.effects,
                        help="light-transport effects: 'auto' (measured on the scene), 'all', or a list of "
                             "indirect, shadows, specular, silhouettes (prefix '-' to force one off, e.g. auto,-shadows)")
    parser.add_argument("--initial-faces", type=int, help=f"faces of the initial mesh ({d.initial_faces})")
    parser.add_argument("--face-growth", type=float, metavar="F",
                        help="multiply the face budget by F (> 1) after each simplification instead of adding half "
                             "the initial face count (the paper's rule): more faces sooner, for finely detailed objects "
                             f"(default: the paper's rule; x{STAGED_FACE_GROWTH} with --material staged)")
    parser.add_argument("--max-levels", type=int, help=f"most coarse-to-fine levels ({d.max_levels})")
    parser.add_argument("--level-iterations", type=int, help=f"most steps per level ({d.level_iterations})")
    parser.add_argument("--step", type=float,
                        help=f"largest vertex step per iteration, in mean edge lengths ({d.step})")
    parser.add_argument("--smoothing", type=float, metavar="LAMBDA", dest="lambda_",
                        help="Large Steps smoothing of the vertex steps (default: 2, or 20 when one constant "
                             "material must explain a textured object; see the stiffness event)")
    parser.add_argument("--integrator", choices=["direct_projective", "prb_projective"], help=f"({d.integrator})")
    parser.add_argument("--max-depth", type=int, help=f"path depth for prb_projective ({d.max_depth})")
    parser.add_argument("--spp", type=int, help=f"samples per pixel per step ({d.spp})")
    parser.add_argument("--remesh", choices=["auto", "always", "never"],
                        help="re-mesh between levels: when inconsistent (auto, the default), always or never")
    parser.add_argument("--track-metrics", action="store_true",
                        help="with ground truth: metrics after every level (time not charged to the budget)")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    parser.add_argument("--plan", action="store_true",
                        help="measure this capture's step costs, print each preset's predicted time and exit "
                             "without running (nothing is written to RUN)")


OVERRIDES = ("init", "material", "effects", "initial_faces", "iterations", "seed", "max_size", "coarse_size", "views_per_step",
             "integrator", "max_depth", "spp", "remesh", "max_levels", "level_iterations", "step", "lambda_",
             "face_growth", "track_metrics")


def choose_preset(args) -> str:
    """The preset asked for; else, with a time budget, the calibrated one that fits it."""
    if args.preset:
        return args.preset
    return preset_for_budget(args.time_budget) if args.time_budget is not None else DEFAULT


def config_from_args(args) -> ReconstructConfig:
    """Defaults, then the preset, then the options given."""
    for name in ("max_size", "coarse_size", "views_per_step", "initial_faces", "spp", "max_levels", "iterations",
                 "time_budget", "max_depth", "level_iterations", "step", "lambda_"):
        value = getattr(args, name)
        flag = "--smoothing" if name == "lambda_" else "--" + name.replace("_", "-")
        require(value is None or value > 0, None, f"{flag} must be positive (got {value})", f"give {flag} a value above 0")
    growth = args.face_growth
    require(growth is None or (math.isfinite(growth) and growth > 1), None,
            f"--face-growth must be above 1 (got {growth})", "give e.g. --face-growth 1.5")
    values = dict(PRESETS[choose_preset(args)])
    values.update(settings_from_environment())
    values.update({k: getattr(args, k) for k in OVERRIDES if getattr(args, k) not in (None, False)})
    values["material"] = MATERIAL_ALIASES.get(values.get("material"), values.get("material")) or DEFAULT_MATERIAL
    if args.time_budget is not None:
        values["time_budget_s"] = 60.0 * args.time_budget
    config = ReconstructConfig(**values)
    config.coarse_size = min(config.coarse_size, config.max_size)
    if config.face_growth is None and config.material == "staged":
        config.face_growth = STAGED_FACE_GROWTH
    return config


VIDEO_SUFFIXES = {".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mts", ".mpg", ".mpeg", ".ogv"}
DEFAULT_MATERIAL = "staged"
MATERIAL_ALIASES = {"constant": "auto", "full": "staged"}
SETTINGS_VARIABLE = "SFT_RECONSTRUCT_SETTINGS"


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
    try:
        with open(Path(run) / "events.jsonl") as f:
            for line in f:
                event = json.loads(line)
                if event.get("event") == "start":
                    return (event.get("settings") or {}).get("material")
    except (OSError, ValueError):
        return None
    return None


def video_inputs(args):
    """The checked inputs of ``capture-from-video`` when PATH is a video with --masks, else None."""
    if args.masks is None:
        path = Path(args.capture)
        require(not (path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES), path,
                "a video needs its object masks", "give --masks MASKS (and the lighting with --env HDR)")
        return None
    from ..video.inputs import check_inputs

    return check_inputs(SimpleNamespace(capture=args.capture, masks=args.masks, env=args.env,
                                        env_rotation=args.env_rotation, align_lighting=args.align_lighting))


def video_capture(inputs, folder, resume: bool, emit):
    """RUN/capture written from the video inputs (kept when resuming), loaded."""
    from ..capture.format import FILENAME
    from ..capture.load import load_capture
    from ..video.inputs import write_capture

    path = folder.path / "capture"
    if not (resume and (path / FILENAME).is_file()):
        write_capture(inputs, path, emit, overwrite=True)
    return load_capture(path)


PATH_OPTIONS = ("--out", "--masks", "--env", "--init")


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
    # Mitsuba loads (and its variant is chosen) only once a run starts, not for --help
    from ..capture.load import load_capture
    from ..lighting.setup import resolve_lighting
    from ..material.constant import parse_spec
    from ..optimize.run_folder import RunFolder

    if args.resume and args.material is None:
        args.material = resumed_material(args.out)
    config = config_from_args(args)
    parse_spec(config.material)  # bad input is reported before anything is written
    video = video_inputs(args)
    capture = load_capture(args.capture) if video is None else None
    config.lighting = resolve_lighting(capture, args.lighting, args.env, args.env_strength, args.env_rotation,
                                       args.capture, video_light=video is not None and video.environment is not None)
    chosen = variant.choose(args.variant)
    from ..optimize.appearance import Appearance
    from ..optimize.run import reconstruct, reported

    if capture is not None:
        Appearance.check(capture, config)
    if getattr(args, "plan", False):
        return _print_plan(args, capture)
    folder = RunFolder.create(args.out, resume=args.resume, overwrite=args.overwrite)
    if not args.resume and getattr(args, "argv", None):
        folder.record_command(absolute_paths(args.argv, args))
    emit = Emitter(log_path=folder.events)
    try:
        with reported(emit):
            emit("start", run=str(folder.path), capture=str(args.capture), settings=dataclasses.asdict(config))
            emit("variant", variant=chosen, llvm=os.environ.get("DRJIT_LIBLLVM_PATH"))
            _preset_event(args, capture, emit, config)
            if video is not None:
                capture = video_capture(video, folder, args.resume, emit)
                Appearance.check(capture, config)
            return reconstruct(capture, folder, config, emit, resume=args.resume).exit_code
    finally:
        emit.close()


def _preset_configs(args, names) -> dict:
    """{preset: its ReconstructConfig with this command line's options}."""
    return {name: config_from_args(SimpleNamespace(**{**vars(args), "preset": name})) for name in names}


def _print_plan(args, capture) -> int:
    """--plan: each preset's predicted time on this capture (optimize/plan.py), printed; no run."""
    from ..optimize.plan import capture_plan

    require(capture is not None, args.capture, "--plan needs a capture folder",
            "write the capture first (capture-from-video), then plan on it")
    plan = capture_plan(capture, _preset_configs(args, PRESETS), calibrated())
    print(plan.table())
    print(f"{plan.line()} on this capture (step costs measured in {plan.costs.seconds:.1f} s)", flush=True)
    # the same as one event (docs/protocol.md) for the add-on's Plan button
    Emitter()("plan", line=plan.line(), **plan.to_json())
    return 0


def _preset_event(args, capture, emit, config) -> None:
    preset = choose_preset(args)
    expected = calibrated().get(preset, {})
    # expected_*: the calibration scene's figures (point-lit: no promise for an HDR-lit capture);
    # predicted_minutes: this capture's own, from its measured step costs (optimize/plan.py)
    comparable = capture is not None and capture.environment is None
    plan = None
    if capture is not None:
        from ..optimize.plan import capture_plan

        plan = capture_plan(capture, {preset: config}, calibrated())
    emit("preset", preset=preset, chosen_for_budget=args.preset is None and args.time_budget is not None,
         expected_minutes=expected.get("expected_minutes") if comparable else None,
         expected_f1=expected.get("expected_f1") if comparable else None,
         calibrated_on=load_calibration().get("scene"),
         predicted_minutes=None if plan is None else round(plan.presets[preset].minutes, 2),
         plan=None if plan is None else {**plan.presets[preset].to_json(), "costs": plan.costs.to_json()},
         note=None if comparable else "calibrated on a point-lit scene; predicted_minutes is this capture's "
                                      "own, from its measured step costs" if plan is not None else
                                      "calibrated on a point-lit scene; the time comes from this capture's "
                                      "measured steps (eta_s)")
