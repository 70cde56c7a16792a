"""A bounded drop-oldest queue with its own worker thread(s): the one home of "never block the caller".

Design notes: docs/bus.md (protocol/ring.py).
"""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable
from typing import Any

log = logging.getLogger("skynet.ring")


class Ring:
    """A bounded drop-oldest queue with its own consumer thread (why: docs/bus.md, protocol/ring.py); overflow
    drops the *oldest* item and counts it. ``workers > 1`` makes it a small pool (for work that releases the GIL,
    such as OpenCV)."""

    def __init__(self, capacity: int, worker: Callable[[Any], None], name: str = "ring", workers: int = 1):
        if capacity < 1 or workers < 1:
            raise ValueError("ring capacity and workers must be >= 1")
        self._items: collections.deque[Any] = collections.deque()
        self._capacity = capacity
        self._cond = threading.Condition()
        self._worker = worker
        self._closed = False
        self.name = name
        self.dropped = 0
        self.processed = 0
        self.failed = 0
        names = [name] if workers == 1 else [f"{name}#{i}" for i in range(workers)]
        self._threads = [threading.Thread(target=self._run, name=n, daemon=True) for n in names]
        for t in self._threads:
            t.start()

    def push(self, item: Any) -> bool:
        """Queue ``item``; False when an older one was dropped to make room (or the ring is closed)."""
        with self._cond:
            if self._closed:
                return False
            kept = True
            if len(self._items) >= self._capacity:
                self._items.popleft()
                self.dropped += 1
                kept = False
            self._items.append(item)
            self._cond.notify()
        return kept

    def __len__(self) -> int:
        return len(self._items)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._items and not self._closed:
                    self._cond.wait()
                if not self._items and self._closed:
                    return
                item = self._items.popleft()
            try:
                self._worker(item)
            except Exception:  # a worker bug must not kill the ring
                with self._cond:
                    self.failed += 1
                log.exception("%s: worker failed", self.name)
            with self._cond:
                self.processed += 1

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def alive(self) -> bool:
        """Whether a worker thread still runs."""
        return any(t.is_alive() for t in self._threads)

    def close(self, timeout: float | None = 2.0, drain: bool = True) -> None:
        """Stop: the workers finish what is queued (or it is dropped, counted, if not ``drain``), then join.

        Idempotent; a worker thread calling it does not join itself.
        """
        with self._cond:
            self._closed = True
            if not drain:
                self.dropped += len(self._items)
                self._items.clear()
            self._cond.notify_all()
        for t in self._threads:
            if threading.current_thread() is not t:
                t.join(timeout)
