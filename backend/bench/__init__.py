"""Benchmarks: ``python -m backend bench NAME [options]``.

Each benchmark is a module ``backend/bench/<name>.py`` whose docstring's first line
describes it and which defines ``add_arguments(parser)`` and ``run(args) -> int``. Modules
are found by name, so a new benchmark is a new file; names starting with ``_`` are helpers.
Listing the benchmarks reads their docstrings from the source without importing them, so a
benchmark's module (and what it imports: Mitsuba, renderers) loads only when it is chosen.

A benchmark starts its child processes through ``_launch`` and ends by writing its figures as
a record, ``bench/records/<name>.json`` (``_records``); ``bench results`` turns the records
into docs/results.md and the README's figures."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import pkgutil
from pathlib import Path


def names() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def load(name: str):
    return importlib.import_module(f"{__name__}.{name}")


def doc(name: str) -> str:
    """The benchmark module's docstring, read from its source (the module is not imported)."""
    origin = importlib.util.find_spec(f"{__name__}.{name}").origin
    return ast.get_docstring(ast.parse(Path(origin).read_text(encoding="utf-8")), clean=False) or ""


def describe(name: str) -> str:
    return doc(name).strip().split("\n")[0]
