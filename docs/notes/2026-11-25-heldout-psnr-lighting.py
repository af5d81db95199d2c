"""Held-out PSNR of a --lighting estimate run on a real capture (docs/notes/2026-11-25-lighting-estimate.md).

    python docs/notes/2026-11-25-heldout-psnr-lighting.py FULL_CAPTURE RUN [--every 8] [--size 96]

Frames i with i % every == 0 were left out of the fit (the run was made on a copy of the capture
without them). Renders the final mesh and material under RUN/environment.exr at those frames and
prints the PSNR (sRGB, inside the object mask) per frame and their mean."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import backend  # noqa: E402,F401

from backend import variant  # noqa: E402

variant.choose()

import numpy as np  # noqa: E402

from backend.capture.load import load_capture  # noqa: E402
from backend.lighting.estimated_map import EstimatedEnvironment  # noqa: E402
from backend.material import factory  # noqa: E402
from backend.metrics.image import psnr  # noqa: E402
from backend.optimize.run_folder import RunFolder  # noqa: E402
from backend.optimize.views import ViewSet  # noqa: E402
from backend.render.scene import RenderSettings, SceneRenderer  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("capture", type=Path)
    p.add_argument("run", type=Path)
    p.add_argument("--every", type=int, default=8)
    p.add_argument("--size", type=int, default=96)
    a = p.parse_args()
    capture = load_capture(a.capture)
    views = [v for i, v in enumerate(ViewSet(capture, a.size).at(a.size)) if i % a.every == 0]
    state, material_path = RunFolder.create(a.run, resume=True, overwrite=False).load_state()
    from backend.geometry.mesh import Mesh

    mesh = Mesh(np.asarray(state["vertices"], np.float64), np.asarray(state["faces"], np.int64))
    material = factory.load(material_path)
    env = EstimatedEnvironment.load(a.run / "environment.exr").environment()
    renderer = SceneRenderer(mesh, material.field, [v.camera for v in views], [v.lights for v in views], env,
                             RenderSettings(spp=128, max_depth=3, integrator="path"))
    scores = {}
    for k, v in enumerate(views):
        pred = renderer.render_numpy(k, seed=k)
        scores[v.name] = psnr(pred, v.target, v.mask)
    print(json.dumps({"held_out": scores, "mean_psnr": float(np.mean(list(scores.values())))}))


if __name__ == "__main__":
    main()
