"""The machine and the code a benchmark ran on, for its records."""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def machine(variant: str | None = None) -> dict:
    """CPU model, cores, memory, Mitsuba variant and versions of this machine."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    info = {"cpu": cpu, "cores": os.cpu_count(), "variant": variant, "platform": platform.platform(),
            "python": platform.python_version()}
    try:
        info["memory_gib"] = round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30, 1)
    except (ValueError, OSError):
        pass
    try:  # inside: this record is also taken where Mitsuba is not installed
        import mitsuba

        info["mitsuba"] = mitsuba.__version__
    except ImportError:
        pass
    return info


def code_version(root: Path = REPO) -> str:
    """The commit the backend runs from: ``git rev-parse HEAD`` (with ``+dirty`` for local
    changes) in a checkout, the ``COMMIT`` file's contents in an exported tree, else 'unknown'."""
    if (root / ".git").exists():
        def git(*args):
            return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True).stdout.strip()
        head = git("rev-parse", "--short=12", "HEAD")
        return head + ("+dirty" if git("status", "--porcelain", "--untracked-files=no") else "") if head else "unknown"
    stamp = root / "COMMIT"
    return stamp.read_text().strip() if stamp.is_file() else "unknown"


def machine_line(info: dict) -> str:
    return f"{info['cpu']}, {info['cores']} cores, {info.get('variant') or 'default variant'}"
