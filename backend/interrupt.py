"""Cancellation by signal.

SIGTERM and SIGINT raise :class:`KeyboardInterrupt` in the main thread and are remembered.
A native library may catch the interrupt inside a callback and raise its own error instead
(Dr.Jit's ``dr.custom`` operations, which Mitsuba's differentiable renders run through, turn
it into a ``RuntimeError`` caused by the interrupt); :func:`is_cancel` still reads that as
the cancel it is, so a signal at any point ends a run as a cancel (exit 130, last snapshot
kept), never as an internal error."""

from __future__ import annotations

import signal

_requested = False


def _handler(signum, frame):
    global _requested
    _requested = True
    raise KeyboardInterrupt


def install() -> None:
    """Route SIGTERM and SIGINT to :func:`_handler` (call once, from the main thread)."""
    signal.signal(signal.SIGTERM, _handler)
    signal.signal(signal.SIGINT, _handler)


def requested() -> bool:
    """Whether a signal asked this process to stop."""
    return _requested


def is_cancel(err: BaseException) -> bool:
    """``err`` is, or was caused by, an interrupt (or one was requested while it was raised)."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return _requested
