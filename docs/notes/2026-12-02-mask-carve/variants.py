import sys, shutil, json
from pathlib import Path
import numpy as np, cv2
sys.argv = sys.argv[:1]
exec(open(__file__.rsplit("/", 1)[0] + "/analyse.py").read().split("caps = {k")[0])
from backend.capture.images import read_mask, write_mask
src = f1dir / "capture-automatic"
def disk(r): return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
variants = {
    "auto&dil(true,3)": lambda a, g: a & cv2.dilate(g.astype(np.uint8), disk(3)).astype(bool),
    "auto&dil(true,1)": lambda a, g: a & cv2.dilate(g.astype(np.uint8), disk(1)).astype(bool),
    "auto|true": lambda a, g: a | g,
    "auto&true": lambda a, g: a & g,
    "true dil 1": lambda a, g: cv2.dilate(g.astype(np.uint8), disk(1)).astype(bool),
    "true ero 1": lambda a, g: cv2.erode(g.astype(np.uint8), disk(1)).astype(bool),
}
for name, fn in variants.items():
    dst = C / "an" / "var"
    shutil.rmtree(dst, ignore_errors=True); shutil.copytree(src, dst)
    for t in sorted((f1dir / "capture-true" / "masks").glob("*.png")):
        a = read_mask(src / "masks" / t.name) > 0.5; g = read_mask(t) > 0.5
        write_mask(dst / "masks" / t.name, fn(a, g).astype(np.float32))
    cap = load_native(dst)
    score(carve(cap), cap, label=name)
