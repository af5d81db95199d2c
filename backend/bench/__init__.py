"""Benchmarks: ``python -m backend bench NAME [options]``.

Each benchmark is a module ``backend/bench/<name>.py`` whose docstring's first line
describes it and which defines ``add_arguments(parser)`` and ``run(args) -> int``. Modules
are found by name, so a new benchmark is a new file; names starting with ``_`` are helpers.
Keep heavy imports inside ``run`` so listing the benchmarks stays fast."""

from __future__ import annotations

import importlib
import pkgutil


def names() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules(__path__) if not m.name.startswith("_"))


def load(name: str):
    return importlib.import_module(f"{__name__}.{name}")


def describe(name: str) -> str:
    doc = load(name).__doc__ or ""
    return doc.strip().split("\n")[0]
