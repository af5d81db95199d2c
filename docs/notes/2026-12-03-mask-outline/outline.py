"""Outline refinements of the automatic masks: per-frame IoU / precision / recall against the true
masks and the initial carve's F1, for each variant given as NAME=JSON (OutlineOptions fields, or
"grabcut": band, "smooth": s, "iterations": k for a band-limited GrabCut round first).

    PYTHONPATH=. python docs/notes/2026-12-03-mask-outline/outline.py [CACHE] NAME=JSON ...
"""
import json, shutil, sys
from pathlib import Path
import numpy as np
here = Path(__file__).resolve().parent
args = [a for a in sys.argv[1:] if "=" in a]
sys.argv = sys.argv[:1] + [a for a in sys.argv[1:] if "=" not in a]
exec((here.parent / "2026-12-02-mask-carve" / "analyse.py").read_text().split("caps = {k")[0])
from backend.capture.images import read_mask, write_mask
from backend.masks.outline import OutlineOptions, refine_outline
from backend.masks.segment import grabcut, mask_seeds
src = f1dir / "capture-automatic"
names = sorted(p.name for p in (src / "masks").glob("*.png"))
truth_m = {n: read_mask(f1dir / "capture-true" / "masks" / n) > 0.5 for n in names}
auto_m = {n: read_mask(src / "masks" / n) > 0.5 for n in names}
from PIL import Image
rgb = {n: np.asarray(Image.open(src / "images" / n).convert("RGB")) for n in names}

def stats(masks):
    i = [((masks[n] & truth_m[n]).sum() / (masks[n] | truth_m[n]).sum()) for n in names]
    p = [((masks[n] & truth_m[n]).sum() / max(masks[n].sum(), 1)) for n in names]
    r = [((masks[n] & truth_m[n]).sum() / truth_m[n].sum()) for n in names]
    return f"IoU {np.mean(i):.4f} P {np.mean(p):.3f} R {np.mean(r):.3f}"

for a in (["base={}"] + args):
    name, spec = a.split("=", 1)
    spec = json.loads(spec)
    out = {}
    for n in names:
        if name == "base":
            out[n] = auto_m[n]
            continue
        m, o = auto_m[n], dict(spec)
        if "grabcut" in o:  # first a band-limited GrabCut round, then (with other fields) the filter
            labels = mask_seeds(m.shape, m.astype(np.float32), int(o.pop("grabcut")))
            m = grabcut(rgb[n], labels, int(o.pop("iterations", 5)), None, float(o.pop("smooth", 0.0))) > 0.5
        out[n] = refine_outline(rgb[n], m.astype(np.float32), OutlineOptions(**o)) > 0.5 if o else m
    dst = C / "an" / f"outline-{name}"
    shutil.rmtree(dst, ignore_errors=True); shutil.copytree(src, dst)
    for n in names:
        write_mask(dst / "masks" / n, out[n].astype(np.float32))
    cap = load_native(dst)
    print(name, json.dumps(spec), stats(out), flush=True)
    score(carve(cap), cap, label=name + " carve")
