"""``reconstruct``: refine a mesh until path-traced renders match the capture, into the run
folder of docs/protocol.md. Exit codes: 0 done, 1 internal error, 2 bad input, 130 cancelled
(SIGTERM, SIGINT or RUN/STOP). ``$SFT_RECONSTRUCT_SETTINGS`` (a JSON object of settings)
applies over the preset and under the options. The command is its options; the job (checks,
config, plan, run) is :mod:`backend.planning.job`."""

from __future__ import annotations

from pathlib import Path

from ..lighting.exposure import HELP as EXPOSURE_HELP, MODES as EXPOSURE_MODES
from ..optimize.camera_fit import HELP as CAMERAS_HELP, MODES as CAMERAS_MODES
from ..lighting.modes import HELP as LIGHTING_HELP, MODES as LIGHTING_MODES
from ..planning import job
from ..optimize.config import STAGED_FACE_GROWTH, ReconstructConfig
from ..planning.presets import DEFAULT, FILL_FACTOR, PRESETS, calibrated
from ..video.inputs import add_lighting_arguments

INIT_HELP = "carve (visual hull; default with masks), sphere, box, spheres (sphere cloud), points (SfM + Poisson), or a mesh file"


def _calibration_help() -> str:
    """Each preset's calibrated time and F1 per kind of lighting (backend/presets.json), for --help."""
    lines = []
    for kind, scene in (("point", "the point-lit dragon"), ("environment", "the HDR-lit armadillo")):
        entries = calibrated(kind=kind)
        if entries:
            parts = [f"{name} ~{e['expected_minutes']:.3g} min, F1@0.01 {100 * e.get('expected_f1', 0):.1f}"
                     + (f" (no gain over {e['dominated_by']})" if e.get("dominated_by") else "")
                     for name, e in entries.items()]
            lines.append(f"on {scene}: {'; '.join(parts)}")
    if not lines:
        return "Not calibrated (python -m backend bench calibrate)."
    return f"Calibrated {' and '.join(lines)} (backend/presets.json; a time budget reads the capture's kind)."


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
    add_lighting_arguments(parser)
    parser.add_argument("--lighting", choices=LIGHTING_MODES, help=LIGHTING_HELP)
    parser.add_argument("--exposure", choices=EXPOSURE_MODES, help=EXPOSURE_HELP)
    parser.add_argument("--refine-cameras", choices=CAMERAS_MODES, help=CAMERAS_HELP)
    parser.add_argument("--map-calibrated", action="store_true",
                        help="the map's strength is calibrated: keep it (no brightness factor is fitted), so the map "
                             "sets the albedo's scale (a captured map or --env only)")
    parser.add_argument("--known-albedo", metavar="R,G,B",
                        help="the object's median albedo (linear RGB in (0, 1)): the albedo is scaled, and the "
                             "light with it, so the median's level is this colour's (default: mean albedo 0.5 "
                             "under a fitted light)")
    parser.add_argument("--out", required=True, type=Path, metavar="RUN", help="run folder")
    parser.add_argument("--preset", choices=sorted(PRESETS),
                        help=f"quality preset (default {DEFAULT}; with --time-budget, the most accurate preset whose "
                             f"calibrated time fits it, or the next one, cut at the budget, when the budget is "
                             f"{FILL_FACTOR:g}x that time); the options below override it. {_calibration_help()}")
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
    parser.add_argument("--texture-stage", choices=["auto", "on", "off"],
                        help="a last material fit at the frames' own size, each face's mesh-color resolution "
                             "set by the frames' pixel footprint on it (auto, the default: when the frames are "
                             "larger than --max-size; report.json texture_stage)")
    parser.add_argument("--texture-size", type=int, metavar="PX",
                        help="with the texture stage: the most pixels on its images' long side (default: the frames')")
    parser.add_argument("--views-per-step", type=int, metavar="K", help=f"views rendered per step ({d.views_per_step})")
    parser.add_argument("--material", default=None,
                        help="'staged' (the default: spatially varying mesh colors, fitted as constants, then "
                             "diffuse, then specular; writes RUN/result.glb), 'constant' (one material for the "
                             "whole object, estimated) or known:ALBEDO_R,G,B:SPECULAR:ROUGHNESS. A resumed run "
                             "keeps the material it started with")
    parser.add_argument("--materials", dest="n_materials", metavar="N|auto",
                        help="with --material staged and no material masks: cluster the frames' colours into N "
                             f"materials, or auto (as many as the colours show); default {d.n_materials}")
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
    parser.add_argument("--primal-spp", type=int, metavar="N",
                        help="samples per pixel of a geometry step's primal image (default: --spp); the backward "
                             "pass keeps --spp (bench samples measures what each count buys)")
    parser.add_argument("--sppp", type=int, metavar="N",
                        help=f"samples per pixel of a geometry step's silhouette term ({d.sppp})")
    parser.add_argument("--remesh", choices=["auto", "always", "never"],
                        help="re-mesh between levels: when inconsistent (auto, the default), always or never")
    parser.add_argument("--track-metrics", action="store_true",
                        help="with ground truth: metrics after every level (charged to the budget)")
    parser.add_argument("--track-accuracy", action="store_true",
                        help="score held-out views every 30 s of run time and at every level's and stage's end "
                             "(charged to the budget): accuracy events, report.json accuracy_time and "
                             "RUN/accuracy_time.png. The capture's ground-truth held-out views when it has them, "
                             "else every 8th view (--held-out-every), which is then not fitted")
    parser.add_argument("--held-out-every", type=int, metavar="K",
                        help=f"with --track-accuracy: hold out every K-th view ({d.held_out_every}; 2K views needed)")
    parser.add_argument("--variant", help="Mitsuba variant (default: automatic)")
    parser.add_argument("--plan", action="store_true",
                        help="measure this capture's step costs, print each preset's predicted time and exit "
                             "without running (nothing is written to RUN)")


def run(args) -> int:
    return job.run(args)
