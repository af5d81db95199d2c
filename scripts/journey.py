"""Try the add-on as a new user would: build the zip, install it into a fresh Blender user
folder, press Install Backend, then click through with the panel's defaults and time each step.

    python scripts/journey.py --video orbit.mp4 [--masks masks/0000.png] [--env map.hdr] --out DIR
        [--truth ORBIT_DIR] [--python PY] [--budget MINUTES]

Runs with the bpy module (the venv's python). Steps: Install Backend (skipped with
``--python``, which names an interpreter that already imports mitsuba), Import Video,
Import Masks (only with ``--masks``; without them the panel's Masks stays Automatic: Solve
Cameras makes them from its own solve), Import Environment Map (only with ``--env``; without a map the panel's
Lighting stays Estimate: the run fits an environment with the material), Solve Cameras,
Reconstruct, Relit Preview, Export glTF, each with the defaults the panel shows
(``--budget`` changes the Time Budget only). With
``--truth`` (a folder written by ``scripts/render_orbit.py``: truth.ply, truth.json) the
result is scored against the true mesh after a similarity fit (as ``bench realworld``).
Writes ``DIR/journey.json`` with the seconds of each step and the figures."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--video", type=Path, required=True)
    p.add_argument("--masks", type=Path,
                   help="one file of the mask sequence, or a mask video (default: none, Masks Automatic)")
    p.add_argument("--env", type=Path, help="the HDR map (default: none, Lighting Estimate)")
    p.add_argument("--out", type=Path, required=True, help="folder for the user folder, capture and results")
    p.add_argument("--truth", type=Path, help="render_orbit.py output folder, to score the result")
    p.add_argument("--python", help="backend interpreter (default: press Install Backend)")
    p.add_argument("--budget", type=float, help="Time Budget in minutes (default: the panel's)")
    p.add_argument("--record", metavar="LABEL",
                   help="also write the row LABEL of the 'journey' benchmark record (bench/records/journey.json; "
                        "rows of other labels are kept)")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="user-", dir=out)  # a fresh user folder
    import bpy  # before anything imports pymeshlab (both ship Embree)

    bpy.context.preferences.use_preferences_save = False
    bpy.context.preferences.system.use_online_access = True  # what the user allows when Install Backend asks
    steps: dict[str, float] = {}

    def step(name, call):
        start = time.monotonic()
        result = call()
        steps[name] = round(time.monotonic() - start, 1)
        print(f"[journey] {name}: {result} in {steps[name]:.1f} s", flush=True)
        if "FINISHED" not in result:
            raise SystemExit(f"{name} did not finish: {result}")

    sys.path.insert(0, str(ROOT))
    from backend.bench._machine import code_version

    built_from = code_version()  # the zip is built from the tree as it is now: later commits are not in it
    scripts = Path(bpy.utils.system_resource("SCRIPTS"))
    dist = out / "dist"
    dist.mkdir(exist_ok=True)
    proc = subprocess.run([sys.executable, str(scripts / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"), "build",
                           "--source-dir", str(ROOT), "--output-dir", str(dist), "--valid-tags",
                           str(scripts / "modules" / "_bpy_internal" / "extensions" / "tags.py")],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(proc.stdout + proc.stderr)
    (zip_path,) = dist.glob("*.zip")
    prefs = bpy.context.preferences
    if prefs.extensions.repos.get("journey") is None:
        prefs.extensions.repos.new(name="journey", module="journey", custom_directory=str(out / "extensions"),
                                   source="USER")
    step("install zip", lambda: bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo="journey",
                                                                         enable_on_install=True))
    name = "bl_ext.journey.shape_from_tracing"
    addon_prefs = prefs.addons[name].preferences
    if args.python:
        addon_prefs.python = args.python
    else:
        step("Install Backend", lambda: bpy.ops.sft.install_backend())
    bpy.ops.wm.read_homefile(use_empty=True)
    sft = bpy.context.scene.sft
    if args.budget is not None:
        sft.time_budget = args.budget
    video = out / args.video.name  # a copy: Import Video puts the capture beside the video
    if not video.exists():
        shutil.copyfile(args.video, video)
    step("Import Video", lambda: bpy.ops.sft.import_video(filepath=str(video)))
    capture = Path(sft.capture_dir)
    manifest = json.loads((capture / "frames.json").read_text())
    if args.masks:
        step("Import Masks", lambda: bpy.ops.sft.import_masks(filepath=str(args.masks.resolve())))
    if args.env:
        step("Import Environment Map", lambda: bpy.ops.sft.import_environment(filepath=str(args.env.resolve())))
    step("Solve Cameras", lambda: bpy.ops.sft.solve_cameras())
    step("Reconstruct", lambda: bpy.ops.sft.reconstruct())
    run = Path(sft.run_dir)
    step("Relit Preview", lambda: bpy.ops.sft.relit_preview())
    step("Export glTF", lambda: bpy.ops.sft.export_gltf(filepath=str(out / "journey.glb")))
    figures = {"steps_s": steps, "total_min": round(sum(steps.values()) / 60, 2),
               "user_min": round(sum(v for k, v in steps.items() if k not in ("install zip", "Install Backend")) / 60, 2),
               "frames": len(manifest["frames"]), "run": str(run), "commit": built_from,
               "settings": {"quality": sft.preset, "time_budget": sft.time_budget, "material": sft.material,
                            "init": sft.init, "effects": sft.effects, "lighting": sft.lighting,
                            "masks": "imported" if args.masks else sft.masks_mode.lower()}}
    if args.truth:
        sys.path.insert(0, str(ROOT))
        from backend.bench.realworld import score

        index_of = {f["name"]: int(f["source_frame"]) for f in manifest["frames"]}
        figures["score"] = score(Path(sft.capture_dir), run, args.truth.resolve(), index_of)
        g = figures["score"]["geometry"]
        print(f"[journey] F1@0.01 {g['f1@0.01']:.1f}, Chamfer-L1 {g['chamfer_l1']:.5f}", flush=True)
    (out / "journey.json").write_text(json.dumps(figures, indent=1))
    if args.record:
        write_journey_record(args, figures, argv)
    print(json.dumps({k: figures[k] for k in ("steps_s", "total_min", "user_min")}), flush=True)
    return 0


# The table's columns; the record's rows also keep every step's minutes and the commit.
SHOWN = ["try", "masks", "lighting", "Solve Cameras (min)", "Reconstruct (min)", "user steps (min)",
         "lighting model", "F1@0.01", "Chamfer-L1", "camera centres max (%)"]


def write_journey_record(args, figures: dict, argv) -> None:
    """One row of the ``journey`` record: each step's minutes, the run's lighting, its figures."""
    sys.path.insert(0, str(ROOT))
    from backend.bench._records import folder, write_record

    steps = figures["steps_s"]
    report = json.loads((Path(figures["run"]) / "report.json").read_text())
    row = {"try": args.record, "frames": figures["frames"], "masks": figures["settings"]["masks"],
           "lighting": figures["settings"]["lighting"],
           "time budget (min)": figures["settings"]["time_budget"],
           **{f"{k} (min)": round(v / 60, 2) for k, v in steps.items() if k not in ("install zip",)},
           "user steps (min)": figures["user_min"], "commit": figures["commit"]}
    model = (report.get("lighting") or {}).get("model")
    if model:
        row["lighting model"] = model
    score = figures.get("score")
    if score:
        row["F1@0.01"] = round(score["geometry"]["f1@0.01"], 1)
        row["Chamfer-L1"] = round(score["geometry"]["chamfer_l1"], 5)
        row["camera centres max (%)"] = round(score["camera_centre_error_pct"]["max"], 2)
    last = folder() / "journey.json"
    if last.is_file() and any("try" not in r for r in json.loads(last.read_text())["figures"]["rows"]):
        last.unlink()  # a table of another layout: its rows cannot merge with these
    args_line = " ".join(str(a) for a in (sys.argv[1:] if argv is None else argv))
    run = f"python scripts/journey.py {args_line}"
    kept = json.loads(last.read_text()).get("commands_run", []) if last.is_file() else []
    write_record("journey", title="The artist's path",
                 context="orbit videos through the Blender panel's defaults on a fresh install: "
                         "built zip, Install Backend, the panel's buttons in order, each step timed",
                 rows=[row], merge_on="try", show=SHOWN, commands_run=[c for c in kept if c != run] + [run],
                 command="python scripts/journey.py --video ORBIT/orbit.mp4 [--masks ORBIT/masks/0000.png] "
                         "[--env MAP.hdr] --truth ORBIT --out TRY --record LABEL")


if __name__ == "__main__":
    sys.exit(main())
