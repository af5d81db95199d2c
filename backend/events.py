"""JSON-lines progress events: the protocol between the backend and the Blender add-on.

Each event is one JSON object on one line of stdout (and appended to ``events.jsonl`` in
the run folder). Every event has ``"event"`` (its kind) and ``"time"`` (seconds since the
emitter started). See docs/protocol.md for the kinds and their fields."""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import threading
import time
from pathlib import Path

from .fsio import space_error


def _clean(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if hasattr(value, "item"):  # numpy scalar
        return _clean(value.item())
    return value


class Emitter:
    """Writes events to a stream (stdout by default) and optionally to a log file.

    The log only ever holds whole lines. When a line cannot be appended (a full disk), the
    log is cut back to its last whole line and closed, and the next event emitted from the
    main thread raises the error (InputError for a full disk or quota), so the failure ends
    the run cleanly even when it happened on a heartbeat thread."""

    def __init__(self, log_path: str | Path | None = None, stream=None, quiet: bool = False):
        self.stream = stream if stream is not None else sys.stdout
        self.quiet = quiet
        self.start = time.perf_counter()
        self.log_path = Path(log_path) if log_path else None
        self.log = open(log_path, "ab", buffering=0) if log_path else None
        self.failure: Exception | None = None

    def __call__(self, event: str, **fields) -> dict:
        record = {"event": event, "time": round(time.perf_counter() - self.start, 3), **_clean(fields)}
        line = json.dumps(record, allow_nan=False)
        if not self.quiet:
            self.stream.write(line + "\n")
            self.stream.flush()
        if self.log:
            self._append((line + "\n").encode())
        if self.failure is not None and threading.current_thread() is threading.main_thread():
            failure, self.failure = self.failure, None
            raise failure
        return record

    def _append(self, data: bytes) -> None:
        size = self.log.tell()
        try:
            if self.log.write(data) != len(data):  # a short write: the disk filled up
                self.log.write(data[-1:])  # raises the error that cut it short
        except OSError as err:
            log, self.log = self.log, None
            with contextlib.suppress(OSError):
                os.ftruncate(log.fileno(), size)
            with contextlib.suppress(OSError):
                log.close()
            self.failure = space_error(self.log_path, err)

    def close(self):
        if self.log:
            self.log.close()
            self.log = None


def null_emitter() -> Emitter:
    return Emitter(quiet=True)


def read_log(path: str | Path) -> list[dict]:
    """The events of a run's ``events.jsonl``, in order; a line a crash cut short is skipped,
    and a missing or unreadable file gives []."""
    try:
        lines = Path(path).read_text().splitlines()
    except OSError:
        return []
    events = []
    for line in lines:
        try:
            events.append(json.loads(line))
        except ValueError:
            continue
    return events
