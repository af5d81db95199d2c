"""Progress events at least once a second, even while a long step (re-meshing) runs."""

from __future__ import annotations

import threading
import time


class Paced:
    """An emitter that first shows every event to the live estimate of the time left
    (``budget.remaining``, a planning.remaining.Remaining once the plan has set it), on the
    budget's clock. A ``progress`` event sent straight to the emitter (a material stage's, the
    lighting's) goes through ``progress`` instead, so that it carries the fraction and time
    left, and the heartbeat repeats its stage, not the last level's. ``budget`` and
    ``progress`` are set by the run once they exist; an estimate that fails is dropped with a
    warning, never stopping the run."""

    def __init__(self, inner):
        self.inner = inner
        self.budget = None  # the run's Budget
        self.progress: Progress | None = None  # the run's Progress while it runs

    def __call__(self, event: str, **fields) -> dict:
        if event == "progress" and "fraction" not in fields and self.progress is not None:
            self.progress.restart(**fields)
            return fields
        budget = self.budget
        if budget is not None and budget.remaining is not None:
            try:
                budget.remaining.observe(event, fields, budget.elapsed())
            except Exception as err:  # an estimate that fails must not stop the run it estimates
                budget.remaining = None
                self.inner("warning", message=f"no estimate of the time left from here on ({type(err).__name__}: {err})")
        return self.inner(event, **fields)

    @property
    def start(self) -> float:
        return self.inner.start


class LockedEmitter:
    """Serialises events from the run loop and the heartbeat thread."""

    def __init__(self, emit):
        self.inner = emit
        self.lock = threading.RLock()  # re-entered when a progress event is re-sent through Progress

    def __call__(self, event: str, **fields) -> dict:
        with self.lock:
            return self.inner(event, **fields)

    @property
    def start(self) -> float:
        return self.inner.start


class StopOnProgress:
    """Checks for a stop request whenever the main thread reports progress, so a cancel also
    ends material stages and effect checks between two of their steps, not only geometry
    steps. Raises once, and only while ``active()`` (not while the outputs are written)."""

    def __init__(self, emit, check_stop, active):
        self.inner, self.check_stop, self.active = emit, check_stop, active
        self.raised = False

    def __call__(self, event: str, **fields) -> dict:
        out = self.inner(event, **fields)
        if (event == "progress" and not self.raised and self.active()
                and threading.current_thread() is threading.main_thread()):
            try:
                self.check_stop()
            except BaseException:
                self.raised = True
                raise
        return out

    @property
    def start(self) -> float:
        return self.inner.start


class Progress:
    """Holds the latest progress fields; emits them when updated (at most ``min_gap`` apart)
    and from a heartbeat thread whenever ``interval`` passes without an event."""

    def __init__(self, emit: LockedEmitter, fraction, elapsed, interval: float = 1.0, min_gap: float = 0.25):
        self.emit, self.fraction, self.elapsed = emit, fraction, elapsed
        self.interval, self.min_gap = interval, min_gap
        self.fields: dict = {}
        self.last = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(timeout=2)

    def update(self, force: bool = False, **fields) -> None:
        self.fields.update(fields)
        if force or time.perf_counter() - self.last >= self.min_gap:
            self._send()

    def restart(self, **fields) -> None:
        """Fields of another kind of work (a material stage's): they replace the last ones but
        the level, and go out at once."""
        self.fields = {k: v for k, v in self.fields.items() if k == "level"}
        self.update(force=True, **{k: v for k, v in fields.items() if k not in ("seconds", "fraction", "eta_s")})

    def _send(self) -> None:
        if not self.fields:
            return
        f = min(max(float(self.fraction()), 0.0), 1.0)
        seconds = self.elapsed()
        eta = seconds * (1 - f) / f if f > 1e-3 else None
        self.last = time.perf_counter()
        self.emit("progress", **self.fields, seconds=round(seconds, 2), fraction=round(f, 4),
                  eta_s=None if eta is None else round(eta, 1))

    def _beat(self) -> None:
        while not self._stop.wait(0.2):
            if time.perf_counter() - self.last >= self.interval:
                self._send()
