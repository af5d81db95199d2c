import sys, json, shutil
from pathlib import Path
import numpy as np
name, opts = sys.argv[1], json.loads(sys.argv[2])
sys.argv = sys.argv[:1]
exec(open(__file__.rsplit("/", 1)[0] + "/analyse.py").read().split("caps = {k")[0])
import mitsuba as mi
from backend.variant import choose; choose()
from backend.bench import masks as B
from backend.masks import MaskOptions
from backend.masks.segment import SeedOptions
if "smooth" in opts: opts["seeds"] = SeedOptions(smooth=opts.pop("smooth"))
r = B.measure(orbit, C / "cow-on-ground-work", MaskOptions(**opts))
P = {n: ((m > .5) & (r["true_masks"][n] > .5)).sum() / max((m > .5).sum(), 1) for n, m in r["masks"].items()}
R = {n: ((m > .5) & (r["true_masks"][n] > .5)).sum() / max((r["true_masks"][n] > .5).sum(), 1) for n, m in r["masks"].items()}
print(f"{name}: IoU {r['mean_iou']:.4f} min {r['min_iou']:.4f} kept {r['kept']} P {np.mean(list(P.values())):.3f} R {np.mean(list(R.values())):.3f}", flush=True)
np.savez_compressed(C / "an" / f"masks-{name}.npz", **r["masks"])
cap = B.write_capture(C / "exp" / f"capture-{name}", r["sfm"], r["frames_rgb"], r["masks"])
cap = load_native(cap)
score(carve(cap), cap, label=name + " carve")
