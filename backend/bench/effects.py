"""Simulate only what a scene calls for: all effects on vs measured selection, per scene.

For each scene the same reconstruction runs twice, with ``--effects all`` (every bounce,
shadow gradients, the specular lobe) and ``--effects auto`` (the measured selection), and
reports the wall-clock ratio and the accuracy of both: F1@0.01, albedo RMSE, held-out PSNR."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from .sweep import REPO, Setting, machine, machine_line, reconstruct_child

SCENES = ("blob_env", "dragon_cornell", "corner")


@dataclass(frozen=True)
class EffectsRun(Setting):
    effects: str = "auto"
    material: str | None = None


def _scene_builders():
    from ._sweep_scenes import DRAGON, SCENES as BASE, Scene, _synth

    scenes = dict(BASE)
    scenes["dragon_cornell"] = Scene(
        "dragon_cornell", "the paper's dragon inside a Cornell-style room (the room is not modelled by the "
        "reconstruction: only the object's masked pixels are fitted), 24 views at 128 px, point lights",
        _synth(mesh=str(DRAGON), up="y", views=24, resolution=128, lighting="points", cornell=True,
               albedo=[0.6, 0.6, 0.6], specular=0.25, roughness=0.35, spp=256, max_depth=6, held_out=4))
    return scenes


def _ensure(name: str, root: Path, emit) -> Path:
    from .. import fsio

    folder = root / name
    if not (folder / "capture.json").is_file():
        with fsio.atomic_dir(folder, replace=True) as tmp:
            _scene_builders()[name].build(tmp, emit)
    return folder


def _score(run: Path, capture: Path) -> dict:
    from ..commands.evaluate import evaluate

    report = evaluate(run, capture, samples=50_000)
    decisions = json.loads((run / "report.json").read_text()).get("effects", [])
    return {"f1": report["geometry"]["f1@0.01"], "chamfer_l1": report["geometry"]["chamfer_l1"],
            "albedo_rmse": report.get("albedo", {}).get("rmse"),
            "psnr": report.get("views", {}).get("held_out", {}).get("psnr"),
            "decision": decisions[-1]["enabled"] if decisions else None}


def add_arguments(parser) -> None:
    parser.add_argument("--scenes", default=",".join(SCENES), help="comma-separated (default: %(default)s)")
    parser.add_argument("--preset", default="draft", help="reconstruct preset for both runs (default: %(default)s)")
    parser.add_argument("--iterations", type=int, default=150,
                        help="optimisation steps of each run: equal work, so the time ratio is the saving "
                             "(default: %(default)s)")
    parser.add_argument("--material", default="staged", help="reconstruct --material (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "bench-effects", help="work folder")


def run(args) -> int:
    from .. import variant
    from ..events import null_emitter

    variant.choose()  # scenes are synthesised (and runs scored) in this process
    emit = null_emitter()
    rows = []
    print(machine_line(machine()), f"load {os.getloadavg()[0]:.1f}", flush=True)
    print(f"{'scene':<15} {'effects':<7} {'seconds':>8} {'F1@1%':>7} {'albedo':>7} {'PSNR':>6}  selected", flush=True)
    for scene in [s for s in args.scenes.split(",") if s]:
        capture = _ensure(scene, args.out / "scenes", emit)
        result = {}
        for mode in ("all", "auto"):
            setting = EffectsRun(name=f"{scene}-{mode}", preset=args.preset, iterations=args.iterations,
                                 effects=mode, material=args.material)
            run_dir = args.out / "runs" / scene / mode
            timing = reconstruct_child(capture, run_dir, setting, args.out / "logs" / f"{scene}-{mode}.log")
            row = {"scene": scene, "effects": mode, "seconds": round(timing["seconds"], 1), "rc": timing["rc"]}
            if timing["rc"] == 0:
                row.update(_score(run_dir, capture))
            result[mode] = row
            rows.append(row)
            fmt = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
            print(f"{scene:<15} {mode:<7} {row['seconds']:>8.1f} {fmt(row.get('f1'), '7.2f')} "
                  f"{fmt(row.get('albedo_rmse'), '7.3f')} {fmt(row.get('psnr'), '6.2f')}  {row.get('decision')}",
                  flush=True)
        a, s = result["all"], result["auto"]
        if a["rc"] == 0 and s["rc"] == 0:
            print(f"{scene:<15} ratio   {a['seconds'] / max(s['seconds'], 1e-9):>8.2f}x faster, "
                  f"F1 {s['f1'] - a['f1']:+.2f}, PSNR {(s['psnr'] or 0) - (a['psnr'] or 0):+.2f} dB", flush=True)
    (args.out / "results.json").write_text(json.dumps(rows, indent=2))
    return 0
