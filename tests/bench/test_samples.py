"""``bench samples`` at toy size: real renders of the HDR-lit scene, one row per configuration,
a clear error for a malformed configuration."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import pytest

from backend.bench import names, samples


def test_registered_and_parses_counts():
    assert "samples" in names()
    assert samples.parse_counts("16,16,4; 32,16,2") == [(16, 16, 4), (32, 16, 2)]
    for bad in ("16,16", "16,0,4", "a,b,c"):
        with pytest.raises(ValueError):
            samples.parse_counts(bad)


def test_a_toy_run_scores_each_configuration_against_the_reference():
    parser = argparse.ArgumentParser()
    samples.add_arguments(parser)
    args = parser.parse_args(["--faces", "1000", "--resolution", "24", "--views", "6", "--seeds", "2",
                              "--ref-seeds", "2", "--ref-spp", "16", "--configs", "4,4,2;8,4,1"])
    assert samples.run(args) == 0
    record = json.loads((Path(os.environ["SFT_RECORDS"]) / "samples.json").read_text())
    rows = record["figures"]["rows"]
    assert [r["P,C,S"] for r in rows] == ["4,4,2", "8,4,1"]
    for r in rows:
        assert 0 < r["step s"] < 60 and -1 <= r["cosine"] <= 1 and r["SNR"] >= 0


def test_a_malformed_configuration_is_exit_2(capsys):
    parser = argparse.ArgumentParser()
    samples.add_arguments(parser)
    assert samples.run(parser.parse_args(["--configs", "16,16"])) == 2
    assert "three positive counts" in capsys.readouterr().err
