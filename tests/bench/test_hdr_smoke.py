"""The HDR step-cost benchmark end to end at a tiny size (real shared mesh and HDR map, real
renders): every configuration is timed and compared with the reference."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import pytest

from backend.bench import hdr


@pytest.mark.skipif(not (hdr.SHARED / hdr.MESHES["armadillo"]).is_file(), reason="shared meshes not present")
def test_hdr_bench_times_and_scores_every_configuration(tmp_path):
    parser = argparse.ArgumentParser()
    hdr.add_arguments(parser)
    out = tmp_path / "hdr.json"
    args = parser.parse_args(["--faces", "600", "--resolution", "16", "--views", "4", "--steps", "1",
                              "--ref-spp", "8", "--ref-sppi", "8", "--ref-rounds", "1", "--out", str(out),
                              "--configs", "sppi=0;sppi=4,guiding=none;sppi=2,guiding_reuse=2"])
    assert hdr.run(args) == 0
    result = json.loads(out.read_text())
    rows = {r["config"]: r for r in result["rows"]}
    assert list(rows) == ["sppi=0", "sppi=4,guiding=none", "sppi=2,guiding_reuse=2"]
    assert 0 < result["self_shadowing"] < 1 and result["faces"] <= 600
    for r in rows.values():
        assert r["step"] > 0 and r["forward"] > 0 and r["backward"] > 0 and -1 <= r["cos"] <= 1
    assert rows["sppi=0"]["guiding"] == 0 and rows["sppi=0"]["shadow_error"] == 1.0
    assert rows["sppi=4,guiding=none"]["guiding"] < 0.05  # a uniform distribution: nothing to build
    octree = rows["sppi=2,guiding_reuse=2"]
    assert octree["guiding"] > 0 and octree["builds"] == 0  # built untimed on the older mesh, then reused
    assert octree["shadow_norm"] > 0
    record = json.loads((Path(os.environ["SFT_RECORDS"]) / "hdr.json").read_text())
    assert [r["samples"] for r in record["figures"]["rows"]] == [4, 2]  # one row per configuration with shadows
    assert all(r["without s"] > 0 and r["ratio"] > 0 for r in record["figures"]["rows"])


def test_configuration_parsing():
    assert hdr.parse_config("sppi=4,guiding=grid,guiding_move=0.5") == {"sppi": 4, "guiding": "grid",
                                                                        "guiding_move": 0.5}
    with pytest.raises(ValueError):
        hdr.parse_config("sppj=4")
