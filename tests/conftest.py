"""Fixtures shared by every test folder (helpers live in tests/helpers.py).

The Mitsuba variant is chosen once here, for the whole test process, as the cli chooses it
for a command: modules that render import Mitsuba's variant types at their tops."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import bpy  # noqa: F401  (bpy must load before pymeshlab: both ship an Embree 4)

from backend import variant  # points Dr.Jit at libLLVM >= 17 before any test imports drjit
from tests.helpers import run_cli

variant.choose()


@pytest.fixture(scope="session", autouse=True)
def _records_elsewhere(tmp_path_factory):
    """Benchmarks run by the tests write their records into a temporary folder (SFT_RECORDS,
    inherited by child processes), never into the checkout's bench/records."""
    os.environ["SFT_RECORDS"] = str(tmp_path_factory.mktemp("records"))


@pytest.fixture(scope="session")
def tiny_capture(tmp_path_factory) -> Path:
    """The built-in object, 8 views at 48 px (64 spp), paper lights, 2 held-out views (a few seconds)."""
    out = tmp_path_factory.mktemp("tiny") / "capture"
    run_cli("synth", "--out", out, "--views", 8, "--resolution", 48, "--spp", 64, "--held-out", 2,
            check=True)
    return out
