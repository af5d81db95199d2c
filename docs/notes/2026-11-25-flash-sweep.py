"""Fitted against true flash intensity x mean albedo (docs/notes/2026-11-25-lighting-flash.md).

    python docs/notes/2026-11-25-flash-sweep.py OUT_DIR

For each case: ``synth --lighting flash`` (8 views, 32 px) of the built-in blob or the
Stanford bunny (shared data) with a known intensity and constant albedo, the lights removed
from capture.json, then ``reconstruct --lighting flash`` at the test's fast settings (20
iterations, 16 px), from the carved visual hull or (``true``) from the true mesh. Under the
convention (mean albedo 0.5) the fitted intensity x 0.5 estimates the true intensity x mean
albedo. Writes OUT_DIR/flash_sweep.json
and OUT_DIR/flash_intensity.png (``OUT_DIR --plot-only`` redraws the figure from the JSON)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SHARED = Path(os.environ.get("SFT_SHARED_DATA", REPO.parent / "shared" / "data"))
BUNNY = SHARED / "meshes" / "shapefromtracing" / "bunny.obj"
DARK, LIGHT = (0.4, 0.3, 0.2), (0.8, 0.7, 0.6)
# (true intensity W/sr, albedo, specular, mesh, start)
CASES = [(0.5, DARK, 0.0, "blob", "carve"), (2.0, DARK, 0.0, "blob", "carve"), (8.0, DARK, 0.0, "blob", "carve"),
         (0.5, LIGHT, 0.0, "blob", "carve"), (2.0, LIGHT, 0.0, "blob", "carve"), (8.0, LIGHT, 0.0, "blob", "carve"),
         (2.0, DARK, 0.25, "blob", "carve"), (2.0, LIGHT, 0.25, "blob", "carve"),
         (2.0, DARK, 0.0, "bunny", "carve"), (2.0, DARK, 0.0, "bunny", "true"),
         (2.0, DARK, 0.25, "bunny", "carve"), (2.0, DARK, 0.25, "bunny", "true")]
FAST = ["--iterations", "20", "--max-size", "16", "--coarse-size", "16", "--initial-faces", "800", "--spp", "4"]


def backend(*args, env=None) -> None:
    subprocess.run([sys.executable, "-m", "backend", *map(str, args)], check=True, cwd=REPO,
                   stdout=subprocess.DEVNULL, env=dict(os.environ, PYTHONPATH=str(REPO), **(env or {})))


def main(out: Path) -> None:
    rows = []
    for k, (intensity, albedo, specular, mesh, start) in enumerate(CASES):
        capture, run = out / f"capture{k}", out / f"run{k}"
        shape = ["--mesh", BUNNY, "--up", "y"] if mesh == "bunny" else []
        backend("synth", "--out", capture, *shape, "--lighting", "flash", "--light-intensity", intensity, "--albedo",
                ",".join(map(str, albedo)), "--specular", specular, "--views", 8, "--resolution", 32, "--spp", 32,
                "--held-out", 0, "--overwrite")
        data = json.loads((capture / "capture.json").read_text())
        for frame in data["frames"]:
            frame.pop("lights")
        (capture / "capture.json").write_text(json.dumps(data))
        effects = ["--effects=-specular"] if specular == 0 else ["--effects", "specular"]
        init = ["--init", capture / "gt" / "mesh.ply"] if start == "true" else []
        backend("reconstruct", capture, "--out", run, "--overwrite", "--lighting", "flash", *FAST, *effects, *init,
                env={"SFT_RECONSTRUCT_SETTINGS": json.dumps({"max_levels": 1, "polish_rounds": 0})})
        lighting = json.loads((run / "report.json").read_text())["lighting"]
        truth = intensity * sum(albedo) / 3
        fitted = lighting["intensity"] * 0.5
        rows.append({"mesh": mesh, "start": start, "intensity": intensity, "albedo": albedo, "specular": specular,
                     "true_product": truth,
                     "fitted_product": fitted, "initial_product": lighting["initial_intensity"] * 0.5,
                     "ratio": fitted / truth})
        print(json.dumps(rows[-1]), flush=True)
    (out / "flash_sweep.json").write_text(json.dumps(rows, indent=1))
    plot(rows, out / "flash_intensity.png")


def plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bars) = plt.subplots(1, 2, figsize=(10, 4.4), dpi=110, gridspec_kw={"width_ratios": [1, 1.1]})
    colours = {("blob", "carve"): "tab:blue", ("bunny", "carve"): "tab:orange", ("bunny", "true"): "tab:green"}
    for (mesh, start), colour in colours.items():
        for specular, fill in ((0.0, colour), (0.25, "none")):
            sel = [r for r in rows if (r["mesh"], r["start"], r["specular"]) == (mesh, start, specular)]
            if sel:
                label = (f"{mesh} from {'true mesh' if start == 'true' else 'hull'}, "
                         f"{'diffuse' if specular == 0 else 'specular 0.25'}")
                ax.scatter([r["true_product"] for r in sel], [r["fitted_product"] for r in sel], s=40,
                           marker="o" if mesh == "blob" else "^", facecolors=fill, edgecolors=colour, label=label)
    ax.scatter([r["true_product"] for r in rows], [r["initial_product"] for r in rows], marker="x", color="grey",
               s=20, label="initial guess (before any fit)")
    ax.plot([0.1, 8.0], [0.1, 8.0], "k--", lw=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("true intensity x mean albedo (W/sr)")
    ax.set_ylabel("fitted intensity x 0.5 (W/sr)")
    ax.legend(fontsize=7)
    names = [f"{r['mesh']} {'true' if r['start'] == 'true' else 'hull'} I={r['intensity']:g} "
             f"rho={sum(r['albedo']) / 3:.1f} s={r['specular']:g}" for r in rows]
    y = range(len(rows))
    bars.barh(list(y), [100 * (r["ratio"] - 1) for r in rows],
              color=[colours[(r["mesh"], r["start"])] for r in rows])
    bars.set_yticks(list(y), names, fontsize=7)
    bars.invert_yaxis()
    bars.axvline(0, color="k", lw=0.8)
    bars.set_xlabel("fitted / true - 1 (%)")
    fig.suptitle("reconstruct --lighting flash: fitted intensity x mean albedo (8 views, 20 iterations, 16 px)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path)


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[2] == "--plot-only":  # redraw from OUT_DIR/flash_sweep.json
        folder = Path(sys.argv[1])
        plot(json.loads((folder / "flash_sweep.json").read_text()), folder / "flash_intensity.png")
    else:
        main(Path(sys.argv[1]))
