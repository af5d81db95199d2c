import sys
from pathlib import Path
import numpy as np, cv2
from backend.capture.images import read_mask
C = Path("/work/wt/masks-cache/cow-on-ground-f1")
def stats(auto_dir, label):
    fpd, fnd = [], []
    for t in sorted((C / "capture-true").glob("masks/*.png")):
        a = read_mask(auto_dir / t.name) > 0.5; g = read_mask(t) > 0.5
        dg = cv2.distanceTransform((~g).astype(np.uint8), cv2.DIST_L2, 5)  # distance to true mask
        da = cv2.distanceTransform((~a).astype(np.uint8), cv2.DIST_L2, 5)
        fpd.append(dg[a & ~g]); fnd.append(da[g & ~a])
    fp, fn = np.concatenate(fpd), np.concatenate(fnd)
    n = len(fpd)
    def h(d): return " ".join(f"{np.sum((d > lo) & (d <= hi)) / n:7.0f}" for lo, hi in ((0, 1.5), (1.5, 3), (3, 6), (6, 15), (15, 1e9)))
    print(f"{label}: per frame FP px by distance to truth (<=1.5,<=3,<=6,<=15,>15): {h(fp)} | FN px by dist to auto: {h(fn)}")
stats(C / "capture-automatic" / "masks", sys.argv[1] if len(sys.argv) > 1 else "auto")
