"""Child processes of the benchmarks: ``python -m backend ...`` (or ``python -c``) with the repository on the path.

Every benchmark starts its children here, so each sees the same environment: this
interpreter, ``PYTHONPATH`` led by the repository, ``PYTHONUNBUFFERED`` (a log is complete up
to the moment a child dies), in this process's working folder unless ``cwd`` says otherwise
(relative paths in its arguments keep their meaning). :func:`run` waits for the
child and measures it (wall and CPU seconds, peak memory, the 1-minute load before and after);
:func:`popen` starts one for a caller that signals or reads it while it runs. A child that
fails becomes one :class:`ChildError` line: what it was, its exit code and the last line it
wrote."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from ._machine import REPO

DEVNULL = subprocess.DEVNULL


class ChildError(RuntimeError):
    """A child that exited non-zero (or ran past its timeout); the message is one line."""


def environment(**extra: str) -> dict:
    """This process's environment with the repository first on ``PYTHONPATH``, unbuffered output
    and ``extra`` on top."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", **extra)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    return env


def backend(*args) -> list[str]:
    """The argv of ``python -m backend ARGS``."""
    return [sys.executable, "-m", "backend", *map(str, args)]


def python(*args) -> list[str]:
    """The argv of ``python ARGS`` (a script, or ``-c CODE``)."""
    return [sys.executable, *map(str, args)]


@dataclass
class Child:
    """A finished child: exit code, what it printed (when captured) and what it cost."""

    argv: list[str]
    rc: int
    seconds: float
    cpu_seconds: float
    peak_mb: float | None
    load_before: float
    load_after: float
    stdout: str = ""
    stderr: str = ""
    log: Path | None = None
    timed_out: bool = False
    extra: dict = field(default_factory=dict)

    @property
    def returncode(self) -> int:
        return self.rc

    def last_line(self, limit: int = 1500) -> str:
        """The last non-empty line the child wrote to stderr (or its log), at most ``limit`` characters."""
        text = self.stderr
        if not text.strip() and self.log is not None and self.log.is_file():
            text = self.log.read_text(errors="replace")
        lines = [line for line in text.strip().splitlines() if line.strip()]
        return (lines[-1] if lines else "(no message)")[-limit:]


def popen(argv: list[str], *, env: dict | None = None, cwd: Path | None = None, **kwargs) -> subprocess.Popen:
    """Start ``argv`` in the benchmarks' environment and return it running (``kwargs`` go to
    :class:`subprocess.Popen`: pipes, ``text``, ``preexec_fn``)."""
    return subprocess.Popen(argv, env=environment() if env is None else env, cwd=cwd, **kwargs)


def run(argv: list[str], *, log: Path | None = None, events: bool = True, timeout: float | None = None,
        what: str | None = None, env: dict | None = None, cwd: Path | None = None) -> Child:
    """Run ``argv`` to its end and measure it.

    Parameters:
        log: the file its output goes to; None captures stdout and stderr as text.
        events: with ``log``, whether stdout (the JSON-lines events) goes to the log too; False
            discards it and logs stderr only.
        timeout: seconds after which the child is killed (the result has ``timed_out``).
        what: when given, a child that fails raises :class:`ChildError` ``"WHAT failed (RC): LAST LINE"``.
        env: its environment (default :func:`environment`).
        cwd: its working folder (default: this process's).
    """
    load_before, start = os.getloadavg()[0], time.perf_counter()
    if log is None:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        try:
            proc = subprocess.run(argv, capture_output=True, text=True, env=environment() if env is None else env,
                                  cwd=cwd, timeout=timeout)
            rc, out, err, timed_out = proc.returncode, proc.stdout, proc.stderr, False
        except subprocess.TimeoutExpired as exc:
            rc, timed_out = -9, True
            out, err = (x.decode(errors="replace") if isinstance(x, bytes) else (x or "")
                        for x in (exc.stdout, exc.stderr))
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu, peak = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), None
    else:
        log = Path(log)
        log.parent.mkdir(parents=True, exist_ok=True)
        out = err = ""
        with open(log, "w") as f:
            proc = popen(argv, env=env, cwd=cwd, stdout=f if events else DEVNULL, stderr=subprocess.STDOUT if events else f)
            killed = threading.Event()

            def kill():
                killed.set()
                proc.kill()

            timer = threading.Timer(timeout, kill) if timeout else None
            if timer:
                timer.start()
            try:
                _, status, usage = os.wait4(proc.pid, 0)
            except BaseException:
                proc.kill()
                proc.wait()
                raise
            finally:
                if timer:
                    timer.cancel()
            proc.returncode = rc = os.waitstatus_to_exitcode(status)
            timed_out = killed.is_set()
        cpu, peak = usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0
    child = Child(list(map(str, argv)), rc, time.perf_counter() - start, cpu, peak, load_before,
                  os.getloadavg()[0], out, err, log, timed_out)
    if what is not None and (rc != 0 or timed_out):
        state = f"timed out after {timeout:g} s" if timed_out else f"failed ({rc})"
        raise ChildError(f"{what} {state}: {child.last_line()}")
    return child
