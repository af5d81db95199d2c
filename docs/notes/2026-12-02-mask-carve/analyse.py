"""Where the F1 is lost: carve and result of each capture vs the truth, by height; per-frame P/R."""
import json, sys
from pathlib import Path
import numpy as np
from backend.capture.format import load_native
from backend.capture.images import read_mask
from backend.geometry.init.carve import carve
from backend.geometry.init.hull import HullConfig
from backend.geometry.mesh import load_mesh
from backend.metrics.geometry import (align_by_icp, align_similarity, geometry_metrics, normalisation,
                                      sample_surface, surface_distance)

C = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("/work/wt/masks-cache")
orbit = C / "cow-on-ground"
f1dir = C / "cow-on-ground-f1"
truth = json.loads((orbit / "truth.json").read_text())
gt = load_mesh(orbit / "truth.ply")
norm = normalisation(gt)
gtn = gt.transformed(norm)
gs = sample_surface(gtn, 100000, 0)
up = 1  # y up in truth

def score(mesh, cap, icp=True, label=""):
    ours = np.array([f.camera.camera_to_world[:3, 3] for f in cap.frames]) if hasattr(cap.frames[0].camera, "camera_to_world") else None
    doc = json.loads((cap.root / "capture.json").read_text())
    ours = np.array([np.array(f["camera"]["camera_to_world"])[:3, 3] for f in doc["frames"]])
    theirs = np.array([np.array(truth["camera_to_world"][int(f["name"])])[:3, 3] for f in doc["frames"]])
    m = mesh.transformed(align_similarity(ours, theirs))
    if icp:
        m = m.transformed(align_by_icp(m, gt))
    g = geometry_metrics(m, gt)
    mn = m.transformed(norm)
    ps = sample_surface(mn, 100000, 0)
    dp = surface_distance(ps.points, gtn, gs)
    dg = surface_distance(gs.points, mn, ps)
    # by height of the truth (normalised, y): bins
    edges = np.linspace(-0.5, 0.5, 6)
    hy = gs.points[:, up]; py = ps.points[:, up]
    rec = [100 * np.mean(dg[(hy >= a) & (hy < b)] < 0.01) if ((hy >= a) & (hy < b)).any() else np.nan for a, b in zip(edges[:-1], edges[1:])]
    pre = [100 * np.mean(dp[(py >= a) & (py < b)] < 0.01) if ((py >= a) & (py < b)).any() else np.nan for a, b in zip(edges[:-1], edges[1:])]
    share = [np.mean((py >= a) & (py < b)) for a, b in zip(edges[:-1], edges[1:])]
    far = 100 * np.mean(dp > 0.05); below = 100 * np.mean(py < gs.points[:, up].min() - 0.01)
    print(f"{label:28s} F1 {g['f1@0.01']:5.1f} P {g['precision@0.01']:5.1f} R {g['recall@0.01']:5.1f} CD {g['chamfer_l1']:.4f} "
          f"| recall by height (low->high) {' '.join(f'{x:5.1f}' for x in rec)} | precision by height {' '.join(f'{x:5.1f}' for x in pre)} "
          f"| pts share {' '.join(f'{x:.2f}' for x in share)} | far>0.05 {far:.1f}% below-feet {below:.1f}%", flush=True)
    return m

caps = {k: load_native(f1dir / f"capture-{k}") for k in ("true", "automatic")}
for k, cap in caps.items():
    P, R = [], []
    if k == "automatic":
        for f, ft in zip(cap.frames, caps["true"].frames):
            a, t = read_mask(f.mask) > 0.5, read_mask(ft.mask) > 0.5
            P.append((a & t).sum() / max(a.sum(), 1)); R.append((a & t).sum() / max(t.sum(), 1))
        print("frames", [f.name for f in cap.frames])
        print("precision", " ".join(f"{p:.3f}" for p in P))
        print("recall   ", " ".join(f"{r:.3f}" for r in R))
    for mv in ([0, 1, 2] if k == "automatic" else [0]):
        try:
            hull = carve(cap, config=HullConfig(miss_views=mv))
            score(hull, cap, icp=True, label=f"{k} carve miss={mv}")
        except Exception as e:
            print(k, mv, "carve failed", e)
    r = f1dir / f"run-{k}" / "result.ply"
    if r.is_file():
        score(load_mesh(r), cap, label=f"{k} result")
