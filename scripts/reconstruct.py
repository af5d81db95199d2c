"""Headless Shape from Tracing: the whole pipeline into a .blend file, plus a relit preview.

    blender --background --python scripts/reconstruct.py -- SOURCE --out scene.blend [options]
    python scripts/reconstruct.py SOURCE --out scene.blend [options]      (the bpy module)

SOURCE is a capture (folder, capture.json, transforms.json or COLMAP model) or a video
(frames are extracted, masks and environment imported, cameras solved by the backend).
Without ``--env`` the panel's Lighting default, Estimate, holds: the run fits an environment
map with the material (RUN/environment.exr), and the relit preview renders under it.
The add-on's operators run as in the UI; the reconstruction is driven synchronously
because timers never fire in background mode. Exit codes: 0 done, 1 failed, 2 bad input,
130 cancelled (Ctrl-C stops the backend cleanly and keeps the last snapshot)."""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "shape_from_tracing"


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="reconstruct.py", description=__doc__.split("\n\n")[0])
    p.add_argument("source", type=Path, help="capture folder / capture.json / transforms.json / COLMAP model, or a video")
    p.add_argument("--out", type=Path, required=True, help=".blend file to write")
    p.add_argument("--python", help="interpreter that runs the backend (default: the add-on's automatic choice)")
    method = p.add_argument_group("method (the Reconstruct panel's settings, same defaults)")
    method.add_argument("--preset", choices=["auto", "draft", "balanced", "final"], default="auto",
                        help="quality; auto: the most accurate preset that fits the time budget")
    method.add_argument("--time-budget", type=float, default=30.0, help="minutes (0: until converged)")
    method.add_argument("--material", choices=["full", "constant"], default="full")
    method.add_argument("--init", choices=["auto", "carve", "sphere", "points"], default="auto")
    method.add_argument("--effects", choices=["auto", "all"], default="auto")
    p.add_argument("--extra", default="", help="further 'python -m backend reconstruct' options, quoted")
    p.add_argument("--run", type=Path, help="run folder (default: <capture>/runs/<date-time>)")
    p.add_argument("--snapshot", type=Path,
                   help="show the newest snapshot of this existing run folder instead of reconstructing")
    video = p.add_argument_group("video input")
    video.add_argument("--capture", type=Path, help="capture folder for the frames (default: <video>_capture)")
    video.add_argument("--every-nth", type=int, default=10)
    video.add_argument("--target-count", type=int, default=40, help="frames to keep (0: every Nth)")
    video.add_argument("--blur-threshold", type=float, default=0.3)
    video.add_argument("--masks", type=Path, help="mask image sequence (one of its files) or mask video")
    lighting = p.add_argument_group("lighting")
    lighting.add_argument("--env", type=Path,
                          help="HDR environment map of the capture (EXR/HDR; default: none, the lighting is estimated)")
    lighting.add_argument("--env-strength", type=float, default=1.0)
    lighting.add_argument("--env-rotation", type=float, default=0.0, help="degrees about Z")
    preview = p.add_argument_group("relit preview")
    preview.add_argument("--preview", type=Path, help="PNG to write (default: beside the .blend file)")
    preview.add_argument("--no-preview", action="store_true")
    preview.add_argument("--preview-frame", type=int, default=0)
    preview.add_argument("--preview-env", type=Path, help="relight with this HDR instead of the captured lighting")
    preview.add_argument("--samples", type=int, default=32)
    preview.add_argument("--percentage", type=int, default=50, help="preview resolution, percent of the frame's")
    preview.add_argument("--device", choices=["AUTO", "CPU", "GPU"], default="AUTO")
    p.add_argument("--gltf", type=Path, help="also export the result as binary glTF (baked textures) here")
    return p.parse_args(argv)


def load_addon(python: str | None):
    """Register the add-on from this repository as the package ``shape_from_tracing``
    (an installed copy of the extension is disabled for this session first)."""
    import addon_utils
    import bpy

    for name in [a.module for a in bpy.context.preferences.addons]:
        if name.endswith(f".{PACKAGE}"):
            addon_utils.disable(name, default_set=False)

    spec = importlib.util.spec_from_file_location(PACKAGE, ROOT / "__init__.py",
                                                  submodule_search_locations=[str(ROOT)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[PACKAGE] = module
    spec.loader.exec_module(module)
    if bpy.context.preferences.addons.get(PACKAGE) is None:
        bpy.context.preferences.addons.new().module = PACKAGE
    module.register()
    if python:
        bpy.context.preferences.addons[PACKAGE].preferences.python = python
    return module


def run(args: argparse.Namespace) -> int:
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)  # start from an empty scene, not the default cube
    load_addon(args.python)
    from shape_from_tracing.addon import jobs
    from shape_from_tracing.addon.video import VIDEO_SUFFIXES

    scene = bpy.context.scene
    sft = scene.sft
    source = args.source.resolve()
    if source.suffix.lower() in VIDEO_SUFFIXES:
        bpy.ops.sft.import_video(filepath=str(source), capture_dir=str(args.capture or ""),
                                 every_nth=args.every_nth, target_count=args.target_count,
                                 blur_threshold=args.blur_threshold, overwrite=True)
        if args.masks:
            bpy.ops.sft.import_masks(filepath=str(args.masks.resolve()))
        if args.env:
            bpy.ops.sft.import_environment(filepath=str(args.env.resolve()), strength=args.env_strength,
                                           rotation_z=args.env_rotation)
        bpy.ops.sft.solve_cameras()
    else:
        bpy.ops.sft.import_cameras(filepath=str(source))
        if args.masks:
            bpy.ops.sft.import_masks(filepath=str(args.masks.resolve()))
        if args.env:
            bpy.ops.sft.import_environment(filepath=str(args.env.resolve()), strength=args.env_strength,
                                           rotation_z=args.env_rotation)
    sft.preset, sft.time_budget = args.preset, args.time_budget
    sft.material, sft.init, sft.effects = args.material.upper(), args.init.upper(), args.effects.upper()
    sft.extra_args = args.extra
    status = "done"
    if args.snapshot:
        snapshot = jobs.latest_snapshot(args.snapshot.resolve())
        if snapshot is None or not jobs.show_snapshot(bpy.context, snapshot):
            print(f"error: {args.snapshot}: no snapshot to show. Fix: give a run folder with snapshot.json",
                  file=sys.stderr)
            return 2
        sft.run_dir = str(args.snapshot.resolve())
    else:
        try:
            result = bpy.ops.sft.reconstruct(run_dir=str(args.run.resolve()) if args.run else "")
        except RuntimeError as err:
            job = jobs.ACTIVE.get("reconstruct")
            if job is None or job.process.returncode is None:
                raise  # refused before starting: bad input
            print(f"error: {str(err).strip().removeprefix('Error: ')}", file=sys.stderr)
            return 2 if job.process.returncode == 2 else 1
        status = jobs.ACTIVE["reconstruct"].state.status
        if "FINISHED" not in result:
            print("reconstruction cancelled before its first snapshot", file=sys.stderr)
            return 130
    out = args.out.resolve()
    if not args.no_preview:
        sft.preview_frame, sft.preview_samples = args.preview_frame, args.samples
        sft.preview_percentage, sft.device = args.percentage, args.device
        sft.preview_env = str(args.preview_env.resolve()) if args.preview_env else ""
        preview = args.preview.resolve() if args.preview else out.with_suffix(".preview.png")
        bpy.ops.sft.relit_preview(filepath=str(preview))
        print(f"preview: {preview}")
    if args.gltf:
        bpy.ops.sft.export_gltf(filepath=str(args.gltf.resolve()))
        print(f"glTF: {args.gltf.resolve()}")
    out.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(out), check_existing=False)
    print(f"saved: {out}")
    return 130 if status == "cancelled" else 0


def main(argv: list[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    args = parse_args(argv)
    try:
        return run(args)
    except RuntimeError as err:  # an operator reported an error: one line, scene not saved
        message = str(err).strip().removeprefix("Error: ").splitlines()[0]
        print(f"error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.exit(code)
