"""``demo``: synthesise the built-in procedural object, reconstruct it, print the metrics
(:func:`backend.demo.demo`, which runs ``synth``, ``reconstruct`` and ``evaluate`` as subprocesses)."""

from __future__ import annotations

from pathlib import Path

from ..demo import demo


def add_arguments(parser):
    parser.add_argument("--out", type=Path, default=Path("demo"), help="folder for the capture and the run")
    parser.add_argument("--minutes", type=float, default=4.0, help="wall-clock budget of the reconstruction")
    parser.add_argument("--views", type=int, default=24)
    parser.add_argument("--resolution", type=int, default=128)


def run(args) -> int:
    return demo(args.out, args.minutes, args.views, args.resolution)
