"""Which Python interpreter runs the backend, and how (bpy-free).

The backend is the pure-Python ``backend/`` package shipped beside ``addon/`` (in the
installed extension and in the repository alike). It runs as ``<python> -m backend`` in a
separate interpreter that can import Mitsuba, with the package's folder as working
directory and on ``PYTHONPATH``."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from .install_backend import installed_python

PACKAGE_DIR = Path(__file__).resolve().parents[2]  # holds addon/ and backend/
VENV_PYTHONS = (".venv/bin/python", ".venv/Scripts/python.exe")  # a developer checkout's interpreter


def default_python(package_dir: Path = PACKAGE_DIR, installed: Path | None = None) -> str:
    """``<package>/.venv``'s interpreter (a developer checkout), else the one Install Backend
    made (``installed``: its environment folder), else ``$SFT_PYTHON``, else ``python3``."""
    for rel in VENV_PYTHONS:
        if (package_dir / rel).is_file():
            return str(package_dir / rel)
    if installed is not None and (python := installed_python(installed)) is not None:
        return str(python)
    if os.environ.get("SFT_PYTHON"):
        return os.environ["SFT_PYTHON"]
    return shutil.which("python3") or shutil.which("python") or "python3"


def has_interpreter(package_dir: Path = PACKAGE_DIR, installed: Path | None = None) -> bool:
    """Whether a backend interpreter was set up (developer .venv, Install Backend or $SFT_PYTHON).
    Asked of each source, not of default_python's answer: with the developer .venv activated,
    its interpreter is also the PATH's python3."""
    if any((package_dir / rel).is_file() for rel in VENV_PYTHONS):
        return True
    if installed is not None and installed_python(installed) is not None:
        return True
    return bool(os.environ.get("SFT_PYTHON"))


def install_command(venv: Path, base: str = sys.executable, package_dir: Path = PACKAGE_DIR) -> list[str]:
    """The command line of Install Backend: ``addon/io/install_backend.py`` run by ``base``."""
    return [base, str(package_dir / "addon" / "io" / "install_backend.py"), "--venv", str(venv),
            "--requirements", str(package_dir / "backend" / "requirements.txt"), "--package", str(package_dir)]


def exists(python: str) -> bool:
    """Whether ``python`` names an interpreter file or a program on PATH."""
    return Path(python).is_file() or shutil.which(python) is not None


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
    return summarise_check(python, proc.stdout.splitlines(), (proc.stderr or proc.stdout).strip().splitlines())


FIX_INSTALL = "press Install Backend in the add-on preferences, or choose an interpreter that imports mitsuba"


def summarise_check(python: str, stdout: list[str], log: list[str]) -> CheckReport:
    """One line from the output of ``<python> -m backend check``: the variant or what is missing."""
    report = None
    for line in reversed(stdout):
        try:
            report = json.loads(line)
            break
        except json.JSONDecodeError:
            continue
    if not isinstance(report, dict) or "missing" not in report:
        tail = " ".join(log[-2:])
        return CheckReport(False, f"{python}: the backend does not run ({tail or 'no output'}). Fix: {FIX_INSTALL}")
    versions = report.get("versions", {})
    if report.get("ok"):
        summary = (f"OK: {variant_text(report)}; Python {report.get('python')}, mitsuba {versions.get('mitsuba')}")
        return CheckReport(True, summary, [], report)
    missing = list(report.get("missing", []))
    names = ", ".join(m.split(" (")[0] for m in missing)
    return CheckReport(False, f"{python}: missing {names}. Fix: {FIX_INSTALL}", missing, report)


def variant_text(report: dict) -> str:
    """e.g. 'CUDA (cuda_ad_rgb)' or 'CPU, LLVM 23 (llvm_ad_rgb)'."""
    variant = str(report.get("variant", "?"))
    if variant.startswith("cuda"):
        return f"CUDA ({variant})"
    llvm = report.get("llvm_version")
    return f"CPU, LLVM {llvm} ({variant})" if llvm else f"CPU ({variant})"
