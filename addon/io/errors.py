"""User-facing errors of the add-on: one line naming the file and the fix (as the backend's)."""

from __future__ import annotations

import os


class AddonInputError(Exception):
    """Bad input. ``str()`` is the single line an operator reports."""

    def __init__(self, path: str | os.PathLike | None, problem: str, fix: str = ""):
        self.path = str(path) if path is not None else None
        self.problem = problem
        self.fix = fix
        where = f"{self.path}: " if self.path else ""
        super().__init__(f"{where}{problem}." + (f" Fix: {fix}" if fix else ""))


def require(condition: bool, path, problem: str, fix: str = "") -> None:
    """Raise :class:`AddonInputError` unless ``condition`` holds."""
    if not condition:
        raise AddonInputError(path, problem, fix)
