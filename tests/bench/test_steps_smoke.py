"""The step-cost split end to end at a tiny size (real shared mesh and HDR map, real renders):
every part of a real geometry step is timed on both paths (Mitsuba's silhouette term and the
project's) and the parts add up to the step (which part costs more between configurations or
paths is left to real sizes: at 16 px it is noise)."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import pytest

from backend.bench import hdr, steps


@pytest.mark.skipif(not (hdr.SHARED / hdr.MESHES["armadillo"]).is_file(), reason="shared meshes not present")
def test_every_part_of_a_step_is_timed():
    parser = argparse.ArgumentParser()
    steps.add_arguments(parser)
    args = parser.parse_args(["--faces", "600", "--resolution", "16", "--views", "4", "--steps", "2", "--warmup", "1",
                              "--ref-spp", "8", "--configs", "sppi=0;sppi=4,guiding=none"])
    assert steps.run(args) == 0
    record = json.loads((Path(os.environ["SFT_RECORDS"]) / "steps.json").read_text())
    rows = {(r["config"], r["path"]): r for r in record["figures"]["rows"]}
    assert list(rows) == [(c, p) for c in ("sppi=0", "sppi=4,guiding=none") for p in ("main", "new")]
    for (config, path), r in rows.items():
        assert r["main/new"] == pytest.approx(rows[config, "main"]["step s"] / r["step s"], abs=0.01)
        assert r["forward"] > 0 and r["backward"] > 0 and r["silhouette"] > 0 and 0 < r["host share"] < 1
        parts = sum(r[p] for p in steps.PARTS)
        assert parts == pytest.approx(r["step s"], rel=0.25)  # medians of parts: close to the median step
