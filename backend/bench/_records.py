"""Benchmark records: one JSON file per benchmark, the figures of its latest run.

A record is ``bench/records/<name>.json`` (a variant of a benchmark, such as a run on CUDA, is
a record of its own: ``hdr-cuda.json``)::

    {"benchmark": "geometry", "title": "Geometry", "context": "one line: what was run",
     "command": "python -m backend bench geometry --out OUT", "commit": "...", "machine": "...",
     "date": "YYYY-MM-DD", "figures": {"columns": [...], "rows": [{column: value}], "scalars": {...}},
     "plots": ["bench/pareto_dragon.png"]}

``figures.rows`` are the benchmark's table, one dict per row with the columns in order;
``figures.scalars`` any single figures. Records a benchmark wrote carry ``machine`` as the
dictionary of :func:`backend.bench._machine.machine`; records carried over from a document
name it in words and say where from (``migrated``). ``python -m backend bench results`` turns
the records into docs/results.md.

Benchmarks write into ``bench/records`` of the repository; ``SFT_RECORDS=DIR`` redirects them
(the tests always do), so a test run never changes the checkout."""

from __future__ import annotations

import json
import math
import os
import shlex
import sys
import time
from pathlib import Path

from .. import fsio
from ._machine import REPO, code_version, machine

RECORDS = REPO / "bench" / "records"
ENV = "SFT_RECORDS"


def folder() -> Path:
    """Where records are written and read: ``$SFT_RECORDS``, else the repository's bench/records."""
    return Path(os.environ.get(ENV) or RECORDS)


def command_line(argv: list[str] | None = None) -> str:
    """This process's command as ``python -m backend ARGS`` (the arguments as given)."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join(["python", "-m", "backend", *map(shlex.quote, map(str, args))])


def columns(rows: list[dict]) -> list[str]:
    """Every key of ``rows``, in the order first seen."""
    return list(dict.fromkeys(k for r in rows for k in r))


def record_name(name: str, variant: str | None) -> str:
    """The record's file name: ``name``, or ``name-cuda`` for a run on a CUDA variant."""
    return f"{name}-cuda" if variant and variant.startswith("cuda") else name


def write_record(name: str, *, title: str, context: str, rows: list[dict] | None = None,
                 scalars: dict | None = None, plots: list[str] | None = None, command: str | None = None,
                 variant: str | None = None, merge_on: str | None = None, into: Path | None = None,
                 **extra) -> Path:
    """Write the record of benchmark ``name`` (replacing its last one); returns its path.

    Parameters:
        rows: ``figures.rows``, one dict per table row (values: numbers, strings or None).
        scalars: ``figures.scalars``.
        plots: image paths, made relative to the repository where they lie inside it.
        command: the reproducing command (default: this process's command line).
        variant: the Mitsuba variant that ran (a CUDA one writes ``NAME-cuda.json``).
        merge_on: a column: the last record's rows whose value there differs from every new
            row's are kept (one benchmark invoked once per scene builds one table; their
            commands are kept in ``commands``).
        extra: further keys of the record.
    """
    name = record_name(name, variant)
    path = Path(into or folder()) / f"{name}.json"
    rows = [dict(r) for r in rows or []]
    command = command or command_line()
    commands = [command]
    if merge_on is not None and path.is_file():
        try:
            last = read(path)
        except ValueError:
            last = {}
        new = {r.get(merge_on) for r in rows}
        rows = [r for r in last.get("figures", {}).get("rows", []) if r.get(merge_on) not in new] + rows
        commands = [c for c in last.get("commands", [last.get("command")]) if c and c != command] + commands
    rel = []
    for p in plots or []:
        p = Path(p)
        try:
            rel.append(str(p.resolve().relative_to(REPO)))
        except ValueError:
            rel.append(str(p))
    record = {"benchmark": name, "title": title, "context": context, "command": command,
              "commit": code_version(), "machine": machine(variant), "date": time.strftime("%Y-%m-%d"),
              "figures": {"columns": columns(rows), "rows": rows, "scalars": dict(scalars or {})},
              "plots": rel, **({"commands": commands} if merge_on is not None else {}), **extra}
    fsio.write_json(path, _plain(record))
    return path


def _plain(value):
    """``value`` with numpy scalars and tuples made JSON values, non-finite floats None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return _plain(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def read(path: Path) -> dict:
    return json.loads(Path(path).read_text())


def load_all(where: Path | None = None) -> dict[str, dict]:
    """Every record in ``where`` (default :func:`folder`), by file name without ``.json``."""
    where = Path(where or folder())
    return {p.stem: read(p) for p in sorted(where.glob("*.json"))} if where.is_dir() else {}
