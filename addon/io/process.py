"""A running backend command: non-blocking reading of its JSON-lines events (bpy-free).

The process I/O of the add-on lives here, as in Blender's extension manager: stdout and
stderr are made non-blocking and drained on each :meth:`BackendProcess.poll`, so a modal
timer (or a headless loop) never waits on the backend. Lines on stdout that parse as a JSON
object with an ``event`` are events (docs/protocol.md); every other line is log text."""

from __future__ import annotations

import collections
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from . import interpreter

EXIT_DONE, EXIT_ERROR, EXIT_BAD_INPUT, EXIT_CANCELLED = 0, 1, 2, 130

if sys.platform == "win32":
    def _make_non_blocking(handle) -> None:
        import msvcrt
        from ctypes import POINTER, byref, windll, wintypes

        set_state = windll.kernel32.SetNamedPipeHandleState
        set_state.argtypes = [wintypes.HANDLE, POINTER(wintypes.DWORD), POINTER(wintypes.DWORD),
                              POINTER(wintypes.DWORD)]
        set_state.restype = wintypes.BOOL
        set_state(msvcrt.get_osfhandle(handle.fileno()), byref(wintypes.DWORD(1)), None, None)

    def _is_would_block(err: OSError) -> bool:
        from ctypes import GetLastError
        return GetLastError() in (0, 232)  # ERROR_NO_DATA
else:
    def _make_non_blocking(handle) -> None:
        os.set_blocking(handle.fileno(), False)

    def _is_would_block(err: OSError) -> bool:
        return isinstance(err, BlockingIOError)


def parse_event(line: str) -> dict | None:
    """The event a stdout line carries, or None when the line is log text."""
    line = line.strip()
    if not line.startswith("{"):
        return None
    try:
        value = json.loads(line)
    except json.JSONDecodeError:
        return None
    return value if isinstance(value, dict) and isinstance(value.get("event"), str) else None


class _LineReader:
    """Splits the bytes of one non-blocking pipe into complete lines."""

    def __init__(self, handle):
        self.handle = handle
        self.pending = b""
        self.eof = False
        _make_non_blocking(handle)

    def read_lines(self) -> list[str]:
        chunks = []
        while not self.eof:
            try:
                chunk = os.read(self.handle.fileno(), 1 << 16)
            except OSError as err:
                if _is_would_block(err):
                    break
                raise
            if not chunk:
                self.eof = True
            chunks.append(chunk)
        data = self.pending + b"".join(chunks)
        *lines, self.pending = data.split(b"\n")
        if self.eof and self.pending:
            lines.append(self.pending)
            self.pending = b""
        return [line.decode("utf-8", errors="replace").rstrip("\r") for line in lines]


class BackendProcess:
    """``<python> -m backend <args>`` running in the background.

    Call :meth:`poll` often; it returns the events that arrived since the last call and
    keeps the last log lines for error reports. :meth:`request_stop` asks for a clean stop
    (``RUN/STOP`` file, then SIGTERM after ``grace_s``, then a kill after ``kill_s``)."""

    def __init__(self, python: str, args: list[str], run_dir: str | os.PathLike | None = None,
                 root: Path = interpreter.PACKAGE_DIR, log_lines: int = 200,
                 grace_s: float = 20.0, kill_s: float = 60.0, argv: list[str] | None = None):
        self.argv = argv or interpreter.command(python, *args)  # argv: another program speaking the protocol
        self.run_dir = Path(run_dir) if run_dir else None
        self.log: collections.deque[str] = collections.deque(maxlen=log_lines)
        self.events: list[dict] = []
        self.grace_s, self.kill_s = grace_s, kill_s
        self.stop_requested_at: float | None = None
        self._signalled = self._killed = False
        self.proc = subprocess.Popen(self.argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     **interpreter.popen_kwargs(root))
        self._out = _LineReader(self.proc.stdout)
        self._err = _LineReader(self.proc.stderr)

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    @property
    def finished(self) -> bool:
        """The process exited and everything it wrote has been read."""
        return self.proc.poll() is not None and self._out.eof and self._err.eof

    def poll(self) -> list[dict]:
        """Events that arrived since the last call (never blocks)."""
        exited = self.proc.poll() is not None  # read after this, so nothing is missed
        new = []
        if self.finished:
            return []
        for line in self._out.read_lines():
            event = parse_event(line)
            if event is None:
                if line.strip():
                    self.log.append(line)
            else:
                new.append(event)
        self.log.extend(line for line in self._err.read_lines() if line.strip())
        if exited and not (self._out.eof and self._err.eof):
            # The pipes can outlive the process (a grandchild holding them): stop waiting.
            self._out.eof = self._err.eof = True
        self.events.extend(new)
        self._escalate_stop()
        if self.finished:
            self.proc.stdout.close()
            self.proc.stderr.close()
        return new

    def request_stop(self) -> None:
        """Ask for a clean stop: the backend finishes its step, snapshots and exits with 130."""
        if self.stop_requested_at is not None or self.proc.poll() is not None:
            return
        self.stop_requested_at = time.monotonic()
        if self.run_dir is not None and self.run_dir.is_dir():
            (self.run_dir / "STOP").touch()
        else:
            self._signal()

    def _signal(self) -> None:
        if not self._signalled and self.proc.poll() is None:
            self._signalled = True
            self.proc.send_signal(signal.CTRL_BREAK_EVENT if sys.platform == "win32" else signal.SIGTERM)

    def _escalate_stop(self) -> None:
        if self.stop_requested_at is None or self.proc.poll() is not None:
            return
        waited = time.monotonic() - self.stop_requested_at
        if waited > self.grace_s:
            self._signal()
        if waited > self.kill_s and not self._killed:
            self._killed = True
            self.proc.kill()

    def kill(self) -> None:
        """Stop at once (Blender is quitting); the last snapshot on disk stays."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()

    def wait(self, timeout: float | None = None, interval: float = 0.05) -> list[dict]:
        """Poll until the process finished (for scripts and tests); returns all new events."""
        start, new = time.monotonic(), []
        while not self.finished:
            new += self.poll()
            if timeout is not None and time.monotonic() - start > timeout:
                raise TimeoutError(f"{' '.join(self.argv)} still running after {timeout:.0f} s")
            time.sleep(interval)
        return new + self.poll()

    def log_tail(self, lines: int = 8) -> str:
        return "\n".join(list(self.log)[-lines:])
