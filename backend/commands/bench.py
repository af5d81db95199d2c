"""``bench``: run a benchmark from the registry in backend/bench/ (one module per benchmark)."""

from __future__ import annotations

from .. import bench


def add_arguments(parser):
    sub = parser.add_subparsers(dest="bench", metavar="NAME")
    for name in bench.names():
        module = bench.load(name)
        p = sub.add_parser(name, help=bench.describe(name), description=module.__doc__)
        module.add_arguments(p)
        p.set_defaults(bench_run=module.run)
    parser.set_defaults(bench_parser=parser)


def run(args) -> int:
    if not getattr(args, "bench_run", None):
        args.bench_parser.print_help()
        return 0
    return int(args.bench_run(args) or 0)
