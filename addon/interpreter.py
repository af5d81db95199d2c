"""Which Python interpreter runs the backend, and how (bpy-free).

The backend is the pure-Python ``backend/`` package shipped beside ``addon/`` (in the
installed extension and in the repository alike). It runs as ``<python> -m backend`` in a
separate interpreter that can import Mitsuba, with the package's folder as working
directory and on ``PYTHONPATH``."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent.parent  # holds addon/ and backend/


def default_python(package_dir: Path = PACKAGE_DIR) -> str:
    """``<package>/.venv``'s interpreter, else ``$SFT_PYTHON``, else ``python3`` on PATH."""
    for rel in (".venv/bin/python", ".venv/Scripts/python.exe"):
        if (package_dir / rel).is_file():
            return str(package_dir / rel)
    if os.environ.get("SFT_PYTHON"):
        return os.environ["SFT_PYTHON"]
    return shutil.which("python3") or shutil.which("python") or "python3"


def has_command(name: str, root: Path = PACKAGE_DIR) -> bool:
    """Whether the backend beside the add-on implements ``name`` (e.g. ``reconstruct``)."""
    return (Path(root) / "backend" / "commands" / f"{name.replace('-', '_')}.py").is_file()


def command(python: str, *args: str) -> list[str]:
    return [python, "-m", "backend", *map(str, args)]


def environment(root: Path = PACKAGE_DIR) -> dict[str, str]:
    """The current environment with ``root`` first on ``PYTHONPATH`` and unbuffered output."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(root), env.get("PYTHONPATH", "")) if p)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def popen_kwargs(root: Path = PACKAGE_DIR) -> dict:
    """Keyword arguments for :class:`subprocess.Popen`: working directory, environment and a
    separate process group, so Ctrl-C in Blender's terminal does not reach the backend."""
    kwargs = {"cwd": str(root), "env": environment(root), "stdin": subprocess.DEVNULL}
    if sys.platform == "win32":
        kwargs["creationflags"] = subprocess.CREATE_NEW_PROCESS_GROUP
    else:
        kwargs["start_new_session"] = True
    return kwargs


def run(python: str, args: list[str], root: Path = PACKAGE_DIR, timeout: float = 600.0) -> tuple[int, str]:
    """Run a short backend command to completion: (exit code, the error line or log tail)."""
    try:
        proc = subprocess.run(command(python, *args), capture_output=True, text=True,
                              timeout=timeout, **popen_kwargs(root))
    except FileNotFoundError:
        return 127, f"{python}: interpreter not found. Fix: choose one in the add-on preferences"
    except subprocess.TimeoutExpired:
        return 124, f"'python -m backend {args[0]}' did not finish in {timeout:.0f} s"
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    if proc.returncode == 2 and lines:
        message = lines[-1].removeprefix("error: ")
    else:
        message = " | ".join(lines[-4:])
    return proc.returncode, message


_OPTIONS: dict[tuple, frozenset[str]] = {}


def command_options(python: str, name: str, root: Path = PACKAGE_DIR) -> frozenset[str]:
    """The ``--options`` a backend command lists in its ``--help`` (cached per version of
    its source file); empty when the command is missing or does not answer."""
    source = Path(root) / "backend" / "commands" / f"{name.replace('-', '_')}.py"
    try:
        key = (python, str(source), source.stat().st_mtime_ns)
    except OSError:
        return frozenset()
    if key not in _OPTIONS:
        try:
            proc = subprocess.run(command(python, name, "--help"), capture_output=True, text=True,
                                  timeout=60, **popen_kwargs(root))
            found = frozenset()
            if proc.returncode == 0:
                found = frozenset(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", proc.stdout))
        except (OSError, subprocess.TimeoutExpired):
            found = frozenset()
        _OPTIONS[key] = found
    return _OPTIONS[key]


@dataclass
class CheckReport:
    """What ``<python> -m backend check`` said about an interpreter."""

    ok: bool
    summary: str
    missing: list[str] = field(default_factory=list)
    details: dict = field(default_factory=dict)


def check(python: str, root: Path = PACKAGE_DIR, timeout: float = 180.0) -> CheckReport:
    """Run the backend's ``check`` command and summarise its answer in one line."""
    try:
        proc = subprocess.run(command(python, "check"), capture_output=True, text=True,
                              timeout=timeout, **popen_kwargs(root))
    except FileNotFoundError:
        return CheckReport(False, f"{python}: interpreter not found. Fix: choose a Python that "
                                  "can import mitsuba in the add-on preferences")
    except subprocess.TimeoutExpired:
        return CheckReport(False, f"{python}: 'python -m backend check' did not answer in {timeout:.0f} s")
    report = None
    for line in reversed(proc.stdout.splitlines()):
        try:
            report = json.loads(line)
            break
        except json.JSONDecodeError:
            continue
    if not isinstance(report, dict):
        tail = " ".join((proc.stderr or proc.stdout).strip().splitlines()[-2:])
        return CheckReport(False, f"{python}: the backend does not run ({tail or 'no output'}). "
                                  f"Fix: install requirements.txt into this interpreter")
    versions = report.get("versions", {})
    if report.get("ok"):
        summary = (f"OK: Python {report.get('python')}, mitsuba {versions.get('mitsuba')}, "
                   f"variant {report.get('variant', '?')}")
        return CheckReport(True, summary, [], report)
    missing = list(report.get("missing", []))
    names = ", ".join(m.split(" (")[0] for m in missing)
    return CheckReport(False, f"{python}: missing {names}. Fix: pip install -r requirements.txt "
                              "into this interpreter", missing, report)
