"""Command line: ``python -m backend <command> [options]``.

Each command lives in ``backend/commands/<name>.py`` with ``add_arguments(parser)`` and
``run(args) -> int``; only the chosen command's module is imported, so ``--help`` stays fast.
Before importing a command that renders, the cli chooses the Mitsuba variant
(``--variant``, else ``SFT_VARIANT``, else automatic; :func:`backend.variant.choose`), as
Mitsuba loads its integrators once a variant is set; the rendering modules then import at
their tops. ``check``, ``import``, ``demo`` (which runs the others as subprocesses) and
listing the benchmarks need no Mitsuba. Bad input ends with one line on stderr and exit
code 2; Ctrl-C or SIGTERM cancels cleanly (exit code 130)."""

from __future__ import annotations

import argparse
import importlib
import sys
import time

from . import __version__, interrupt, variant
from .errors import EXIT_BAD_INPUT, InputError

COMMANDS = {
    "synth": "Render a synthetic capture of a mesh (or the built-in procedural object).",
    "import": "Convert an importable capture (transforms.json, COLMAP, IDR npz, Middlebury) to our format.",
    "reconstruct": "Refine a mesh and material until path-traced renders match the capture.",
    "evaluate": "Compare a reconstruction with ground truth: Chamfer, F1, PSNR/SSIM, albedo RMSE.",
    "capture-from-video": "Turn a phone video, masks and an HDR map into a capture (frames, SfM, lighting).",
    "bench": "Benchmarks: geometry, material, sweep, calibrate, stability, effects, hdr, realworld, sfm.",
    "labels": "Write the material labels Reconstruct would cluster as colour overlays on the frames.",
    "check": "Report whether this interpreter can run the backend (for the Blender add-on).",
    "demo": "Synthesise the built-in procedural object, reconstruct it and print the metrics.",
}


RENDERS = {"synth", "reconstruct", "evaluate", "capture-from-video", "labels"}  # and a named benchmark: bench NAME


def _positionals(argv: list[str]) -> list[str]:
    return [a for a in argv if not a.startswith("-")]


def needs_variant(argv: list[str]) -> bool:
    """Whether the command line runs a command whose modules render (and so need the variant
    chosen before they are imported): a command of ``RENDERS``, or ``bench NAME``."""
    words = _positionals(argv)
    return bool(words) and (words[0] in RENDERS or (words[0] == "bench" and len(words) > 1))


def _module(name: str):
    return importlib.import_module(f".commands.{name.replace('-', '_')}", __package__)


def build_parser(argv: list[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m backend", description=__doc__.split("\n\n")[0])
    parser.add_argument("--version", action="version", version=f"shape-from-tracing {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    wanted = next((a for a in argv if not a.startswith("-")), None)
    for name, help_text in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == wanted:  # only the chosen command's module is imported
            _module(name).add_arguments(p)
            p.set_defaults(func=_module(name).run)
    return parser


def main(argv: list[str] | None = None) -> int:
    started = time.perf_counter()  # a command's time budget counts from here (backend.optimize.budget)
    argv = sys.argv[1:] if argv is None else argv
    interrupt.install()
    try:
        if needs_variant(argv):
            variant.choose(variant.requested(argv))  # silent: the command announces it in its events
    except InputError as err:
        print(f"error: {err.line()}", file=sys.stderr)
        return EXIT_BAD_INPUT
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if not argv else EXIT_BAD_INPUT
    args.argv = argv  # the command line as given (reconstruct records it for a later resume)
    args.started = started
    try:
        return int(args.func(args) or 0)
    except InputError as err:
        print(f"error: {err.line()}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as err:
        if not interrupt.is_cancel(err):  # a library's wrapping of the interrupt is still a cancel
            raise
        print("cancelled", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("cancelled", file=sys.stderr)
        return 130
