"""JSON-lines progress events: the protocol between the backend and the Blender add-on.

Each event is one JSON object on one line of stdout (and appended to ``events.jsonl`` in
the run folder). Every event has ``"event"`` (its kind) and ``"time"`` (seconds since the
emitter started). See docs/protocol.md for the kinds and their fields."""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path


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
    """Writes events to a stream (stdout by default) and optionally to a log file."""

    def __init__(self, log_path: str | Path | None = None, stream=None, quiet: bool = False):
        self.stream = stream if stream is not None else sys.stdout
        self.quiet = quiet
        self.start = time.perf_counter()
        self.log = open(log_path, "a", buffering=1) if log_path else None

    def __call__(self, event: str, **fields) -> dict:
        record = {"event": event, "time": round(time.perf_counter() - self.start, 3), **_clean(fields)}
        line = json.dumps(record, allow_nan=False)
        if not self.quiet:
            self.stream.write(line + "\n")
            self.stream.flush()
        if self.log:
            self.log.write(line + "\n")
        return record

    def close(self):
        if self.log:
            self.log.close()
            self.log = None


def null_emitter() -> Emitter:
    return Emitter(quiet=True)
