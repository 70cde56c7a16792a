"""Stopping on SIGINT/SIGTERM: the one way every command of the project stops (no Zenoh needed)."""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Iterator, Sequence

__all__ = ["STOP_SIGNALS", "StopEvent", "stop_event_on_signals", "stopping_on_signals"]

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
POLL_S = 0.2  # how late a signal taken by another thread may stop a waiting main thread


class StopEvent(threading.Event):
    """An event whose :meth:`wait` wakes every ``POLL_S``, so a signal's Python handler runs (on the main thread
    only, when it runs Python code) even when the kernel gave the signal to a thread of Zenoh's runtime.

    The handler only stores a flag (:meth:`signal`): ``Event.set`` takes the event's lock, which the main thread
    may hold at the bytecode the handler interrupts (Python's ``signal`` docs), so the polls set the event.
    """

    signalled = False

    def signal(self) -> None:
        """Ask the event to be set by the next poll: safe in a signal handler (no lock)."""
        self.signalled = True

    def is_set(self) -> bool:
        return self.signalled or super().is_set()

    def wait(self, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            left = POLL_S if deadline is None else min(POLL_S, deadline - time.monotonic())
            if self.signalled:
                self.set()
            if super().wait(max(left, 0.0)) or self.signalled or (deadline is not None and left <= 0):
                return self.is_set()


def stop_event_on_signals(signals: Sequence[int] = STOP_SIGNALS) -> StopEvent:
    """An event set by SIGINT/SIGTERM, so a main loop can close cleanly (the one way every command stops).

    Off the main thread (where Python cannot install handlers) the event is returned unhooked.
    """
    stop = StopEvent()
    if threading.current_thread() is threading.main_thread():
        for s in signals:
            signal.signal(s, lambda signum, frame: stop.signal())
    return stop


@contextlib.contextmanager
def stopping_on_signals(signals: Sequence[int] = STOP_SIGNALS) -> Iterator[StopEvent]:
    """:func:`stop_event_on_signals` for a command run in-process: the previous handlers come back on exit."""
    previous = {s: signal.getsignal(s) for s in signals} if threading.current_thread() is threading.main_thread() else {}
    try:
        yield stop_event_on_signals(signals)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
