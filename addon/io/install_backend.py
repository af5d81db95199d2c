"""Install the backend's interpreter: a virtual environment with the pinned requirements.

Runs as a script with any Python 3.11 (Blender's own, from the preferences' Install Backend
button; stdlib only, bpy-free)::

    python install_backend.py --venv DIR --requirements backend/requirements.txt --package ROOT

and reports JSON-lines events on stdout as the backend does (docs/protocol.md): ``stage``
(venv, download, install, check), ``progress`` (``fraction``, ``package``), then ``done``
(``python``: the new interpreter; ``check``: what ``python -m backend check`` said) or
``error`` (one line with the fix). The environment is built beside ``DIR``, in
``.DIR.installing``, and counts as installed only once its marker file ``INSTALLED`` exists,
written last; then it replaces ``DIR`` by renames (the previous environment is moved to
``.DIR.previous`` and removed once the new one is in place). A failed or cancelled install
(SIGTERM) removes only the folder it was building: an environment already in ``DIR`` stays
as it was, so a re-install without a network keeps the backend working. Exit codes: 0 done,
1 failed, 2 offline or bad input, 130 cancelled."""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

MARKER = "INSTALLED"
# pip lines that mean the package index cannot be reached
OFFLINE = re.compile(r"Failed to establish a new connection|Network is unreachable|Temporary failure in name "
                     r"resolution|Name or service not known|No matching distribution found|Could not find a "
                     r"version that satisfies|ConnectionError|Read timed out|getaddrinfo failed", re.I)
COLLECTING = re.compile(r"^\s*(?:Collecting|Requirement already satisfied:|Using cached|Processing)\s+([A-Za-z0-9_.\-]+)")
STAGES = {"venv": (0.0, 0.05), "download": (0.05, 0.7), "install": (0.7, 0.93), "check": (0.93, 1.0)}
EXPECTED_PACKAGES = 14  # direct and indirect requirements, for the download stage's fraction


def venv_python(venv: Path) -> Path:
    return venv / ("Scripts/python.exe" if sys.platform == "win32" else "bin/python")


def staging_folder(venv: Path) -> Path:
    """Where an install builds the environment that replaces ``venv`` once it works."""
    return venv.with_name(f".{venv.name}.installing")


def previous_folder(venv: Path) -> Path:
    """Where the replaced environment waits while the new one moves in."""
    return venv.with_name(f".{venv.name}.previous")


def installed_python(venv: Path) -> Path | None:
    """The environment's interpreter once an install finished, else None."""
    python = venv_python(venv)
    return python if (venv / MARKER).is_file() and python.is_file() else None


class Cancelled(Exception):
    pass


class Installer:
    def __init__(self, venv: Path, requirements: Path, package: Path, base: str = sys.executable):
        self.venv, self.requirements, self.package, self.base = venv, requirements, package, base
        self.staging = staging_folder(venv)
        self.child: subprocess.Popen | None = None
        self.start = time.monotonic()
        self.switching = False  # a cancel waits while the new environment moves in

    def emit(self, event: str, **fields) -> None:
        print(json.dumps({"event": event, "time": round(time.monotonic() - self.start, 3), **fields}), flush=True)

    def progress(self, stage: str, within: float, **fields) -> None:
        lo, hi = STAGES[stage]
        self.emit("progress", stage=stage, fraction=round(lo + (hi - lo) * min(1.0, within), 4), **fields)

    def run(self) -> int:
        if not self.requirements.is_file():
            self.emit("error", message=f"{self.requirements}: requirements file not found. Fix: reinstall the extension")
            return 2
        shutil.rmtree(self.staging, ignore_errors=True)  # a build an earlier install left
        try:
            self.emit("stage", stage="venv", path=str(self.venv))
            self._call([self.base, "-m", "venv", str(self.staging)], "venv")
            python = str(venv_python(self.staging))
            self.emit("stage", stage="download")
            self._pip(python)
            self.emit("stage", stage="check")
            self._call([python, "-c", "pass"], "check")  # lets karellen-llvm-core create its libLLVM links
            report = self._check(python)
            if not report.get("ok"):
                missing = ", ".join(m.split(" (")[0] for m in report.get("missing", [])) or "unknown"
                raise RuntimeError(f"the new interpreter cannot run the backend (missing {missing})")
            final = str(venv_python(self.venv))
            (self.staging / MARKER).write_text(json.dumps({"python": final, "check": report}))
            self._switch()
            self.emit("done", python=final, check=report, seconds=round(time.monotonic() - self.start, 1))
            return 0
        except Cancelled:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.emit("cancelled")
            return 130
        except OfflineError as err:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.emit("error", message=str(err))
            return 2
        except Exception as err:  # any failure: nothing half-installed stays, the environment in use is kept
            shutil.rmtree(self.staging, ignore_errors=True)
            self.emit("error", message=f"{err}. Fix: check the log, or choose an interpreter that imports mitsuba "
                                       f"in the preferences")
            return 1

    def _switch(self) -> None:
        """The checked environment replaces ``venv`` by renames; the previous one is removed
        only once the new one is in place, and put back if the new one cannot move in."""
        self.switching = True
        previous = previous_folder(self.venv)
        shutil.rmtree(previous, ignore_errors=True)
        try:
            if self.venv.exists():
                try:
                    self.venv.rename(previous)
                except OSError as err:
                    raise RuntimeError(f"cannot replace {self.venv} ({err.strerror}): close the backend runs "
                                       f"that use it") from None
            try:
                self.staging.rename(self.venv)
            except OSError as err:
                if previous.exists():
                    previous.rename(self.venv)
                raise RuntimeError(f"cannot move the new environment to {self.venv} ({err.strerror})") from None
            shutil.rmtree(previous, ignore_errors=True)
        finally:
            self.switching = False

    def _lines(self, argv: list[str]):
        """Run ``argv``, yielding its output lines; raises on a non-zero exit."""
        env = dict(os.environ, PYTHONUNBUFFERED="1", PIP_DISABLE_PIP_VERSION_CHECK="1", PIP_NO_INPUT="1")
        env.pop("PYTHONPATH", None)
        env.pop("PYTHONHOME", None)
        self.child = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                                      stdin=subprocess.DEVNULL)
        tail = []
        for line in self.child.stdout:
            line = line.rstrip()
            if line:
                tail = (tail + [line])[-20:]
                yield line
        code = self.child.wait()
        self.child = None
        if code != 0:
            raise ProcessError(code, tail)

    def _call(self, argv: list[str], stage: str) -> None:
        try:
            for line in self._lines(argv):
                print(line, file=sys.stderr, flush=True)
        except ProcessError as err:
            raise RuntimeError(f"'{' '.join(argv[1:3])}' failed (exit {err.code}): {err.last()}") from None
        self.progress(stage, 1.0)

    def _pip(self, python: str) -> None:
        seen: list[str] = []
        argv = [python, "-m", "pip", "install", "--progress-bar", "off", "-r", str(self.requirements)]
        try:
            for line in self._lines(argv):
                print(line, file=sys.stderr, flush=True)
                match = COLLECTING.match(line)
                if match and match.group(1).lower() not in seen:
                    seen.append(match.group(1).lower())
                    self.progress("download", len(seen) / EXPECTED_PACKAGES, package=match.group(1))
                elif line.startswith("Installing collected packages"):
                    self.emit("stage", stage="install")
                    self.progress("install", 0.0)
        except ProcessError as err:
            if any(OFFLINE.search(line) for line in err.tail):
                raise OfflineError("cannot reach the Python package index to download the backend's libraries "
                                   "(about 340 MB). Fix: connect to the internet and press Install Backend again, "
                                   "or choose an interpreter that imports mitsuba in the preferences") from None
            raise RuntimeError(f"pip failed (exit {err.code}): {err.last()}") from None
        self.progress("install", 1.0)

    def _check(self, python: str) -> dict:
        env = dict(os.environ, PYTHONPATH=str(self.package), PYTHONUNBUFFERED="1")
        for inherited in ("PYTHONHOME", "DRJIT_LIBLLVM_PATH"):  # the new environment must stand alone
            env.pop(inherited, None)
        self.child = subprocess.Popen([python, "-m", "backend", "check"], stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, text=True, cwd=str(self.package), env=env,
                                      stdin=subprocess.DEVNULL)
        out, err = self.child.communicate()
        self.child = None
        self.progress("check", 1.0)
        for line in reversed(out.splitlines()):
            try:
                return json.loads(line)
            except ValueError:
                continue
        raise RuntimeError(f"'python -m backend check' gave no answer: {err.strip()[-300:]}")

    def cancel(self, *_args) -> None:
        if self.switching:  # the new environment is moving in: the install completes
            return
        if self.child is not None and self.child.poll() is None:
            self.child.kill()
        raise Cancelled


class ProcessError(Exception):
    def __init__(self, code: int, tail: list[str]):
        super().__init__(code)
        self.code, self.tail = code, tail

    def last(self) -> str:
        useful = [line for line in self.tail if "error" in line.lower()] or self.tail
        return useful[-1] if useful else "no output"


class OfflineError(Exception):
    pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--venv", required=True, type=Path,
                        help="folder of the environment (replaced only once the new one works)")
    parser.add_argument("--requirements", required=True, type=Path)
    parser.add_argument("--package", required=True, type=Path, help="folder holding backend/")
    args = parser.parse_args(argv)
    installer = Installer(args.venv.resolve(), args.requirements.resolve(), args.package.resolve())
    signal.signal(signal.SIGTERM, installer.cancel)
    if sys.platform == "win32":
        signal.signal(signal.SIGBREAK, installer.cancel)
    try:
        return installer.run()
    except KeyboardInterrupt:
        installer.emit("cancelled")
        return 130


if __name__ == "__main__":
    sys.exit(main())
