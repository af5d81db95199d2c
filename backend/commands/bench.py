"""``bench``: run a benchmark from the registry in backend/bench/ (one module per benchmark).

The benchmarks ship with the source repository only (the extension zip leaves
``backend/bench`` out), so without them the command answers with one line."""

from __future__ import annotations

import argparse
from importlib.util import find_spec

from ..errors import InputError

MISSING = ("benchmarks ship with the source repository, not with the Blender extension",
           "clone the repository and run python -m backend bench there")


def _registry():
    """``backend.bench``, or None where it is not installed (the extension zip)."""
    if find_spec(f"{__package__.rpartition('.')[0]}.bench") is None:
        return None
    from .. import bench  # here: the package may be absent (the extension ships without it)

    return bench


class _BenchParser(argparse.ArgumentParser):
    """A benchmark's parser: its module is imported and its options added only when the command
    line chooses it, so listing the benchmarks imports none of them."""

    bench_name: str | None = None

    def parse_known_args(self, args=None, namespace=None):
        if self.bench_name is not None:
            module = _registry().load(self.bench_name)
            self.bench_name = None
            module.add_arguments(self)
            self.set_defaults(bench_run=module.run)
        return super().parse_known_args(args, namespace)


def add_arguments(parser):
    bench = _registry()
    parser.set_defaults(bench_parser=parser)
    if bench is None:
        parser.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
        return
    sub = parser.add_subparsers(dest="bench", metavar="NAME", parser_class=_BenchParser)
    for name in bench.names():
        p = sub.add_parser(name, help=bench.describe(name), description=bench.doc(name))
        p.bench_name = name


def run(args) -> int:
    if _registry() is None:
        raise InputError(None, *MISSING)
    if not getattr(args, "bench_run", None):
        args.bench_parser.print_help()
        return 0
    return int(args.bench_run(args) or 0)
