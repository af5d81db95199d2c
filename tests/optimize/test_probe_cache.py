"""What a run measures before its first step, kept beside the capture (backend/capture/probe_cache.py):
a second run on the same capture skips the effects probes and the carving and makes the same
decision from the same mesh; an edited capture misses."""

from __future__ import annotations

import json
import shutil

import numpy as np
from PIL import Image

from backend.bench.budget import before_first_step
from backend.geometry.mesh import load_mesh
from tests.helpers import run_cli

OPTIONS = ["--max-size", "32", "--coarse-size", "32", "--initial-faces", "600", "--spp", "4", "--init", "carve",
           "--iterations", "2", "--material", "auto", "--effects", "auto", "--texture-stage", "off"]


def _run(capture, out):
    proc = run_cli("reconstruct", capture, "--out", out, *OPTIONS, check=True)
    events = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    # the first run's decision is complete once its cost probe has run (after the first step)
    decisions = [e for e in events if e["event"] == "effects"]
    decision = next((e for e in decisions if e["reason"] == "initial mesh: cost probe"), decisions[0])
    return decision, load_mesh(out / "snapshots" / "000000.ply"), before_first_step(events)


def _same(first: dict, second: dict) -> None:
    assert second["enabled"] == first["enabled"]
    assert second["why"] == first["why"]
    plain = {k: v for k, v in first["measured"].items() if k not in ("seconds", "costs_measured_at")}
    again = {k: v for k, v in second["measured"].items() if k not in ("seconds", "costs_measured_at", "cache")}
    assert again == plain


def test_second_run_reuses_the_probes_and_an_edit_misses(tmp_path):
    capture = tmp_path / "capture"
    run_cli("synth", "--out", capture, "--views", 6, "--resolution", 32, "--spp", 16, "--held-out", 0,
            "--lighting", "env", "--env", "sky", check=True)
    first, mesh, before = _run(capture, tmp_path / "one")
    assert "cache" not in first["measured"] and "costs" in first["measured"]  # measured, cost probe included
    assert {"init", "effects:bounces"} <= set(before)  # what ran before the first step
    assert "effects:costs" not in before  # the cost probe waits for the first step
    assert (capture / ".sft-cache" / "effects.json").is_file()
    assert (capture / ".sft-cache" / "initial_mesh.json").is_file()

    second, mesh_again, before_again = _run(capture, tmp_path / "two")
    assert second["measured"]["cache"] == "hit"
    assert second["seconds"] < first["seconds"]
    _same(first, second)
    assert "effects:cached" in before_again and "effects:costs" not in before_again
    assert np.array_equal(mesh_again.faces, mesh.faces)
    assert np.allclose(mesh_again.vertices, mesh.vertices, atol=1e-6)  # the PLY's float32

    edited = tmp_path / "edited"
    shutil.copytree(capture, edited)
    image = sorted((edited / "images").iterdir())[0]
    pixels = np.asarray(Image.open(image)) if image.suffix != ".exr" else None
    if pixels is not None:
        Image.fromarray(np.clip(pixels.astype(np.int32) + 1, 0, 255).astype(pixels.dtype)).save(image)
    else:
        image.write_bytes(image.read_bytes())  # rewritten: a newer time
    third, _, _ = _run(edited, tmp_path / "three")
    assert "cache" not in third["measured"]
