"""User-facing errors: one line naming the file and the fix, exit code 2."""

from __future__ import annotations

import os

EXIT_BAD_INPUT = 2


class InputError(Exception):
    """Bad user input. ``str()`` is the single line the CLI prints."""

    def __init__(self, path: str | os.PathLike | None, problem: str, fix: str = ""):
        self.path = str(path) if path is not None else None
        self.problem = problem
        self.fix = fix
        super().__init__(self.line())

    def line(self) -> str:
        where = f"{self.path}: " if self.path else ""
        fix = f" Fix: {self.fix}" if self.fix else ""
        return f"{where}{self.problem}.{fix}".replace("\n", " ")


def require(condition: bool, path, problem: str, fix: str = "") -> None:
    """Raise :class:`InputError` unless ``condition`` holds."""
    if not condition:
        raise InputError(path, problem, fix)
