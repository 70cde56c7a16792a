"""The page's defect count, counted as the mission report counts it.

Design notes: docs/operator-view.md (services/web/tally.py).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

from .view import FleetView

log = logging.getLogger(__name__)

#: seconds between two counts at least (a count of a 60-capture mission takes a few seconds of one core)
INTERVAL_S = 10.0


def count_defects(frames_dir: str, corners: Sequence[Sequence[float]] | None) -> tuple[int, int]:
    """(defects, captures) of the folder as the report counts them: the report's own loader, plane and
    :func:`~services.inspection.deliverable.inspect_frames`. ValueError when the folder cannot be read yet."""
    from services.inspection.deliverable import inspect_frames, load_folder
    from services.inspection.mosaic import Plane

    frames, _, _ = load_folder(frames_dir)
    if not frames:
        return 0, 0
    plane = Plane.from_corners(corners) if corners is not None and len(corners) == 4 else None
    return len(inspect_frames(frames, plane).defects), len(frames)


def _worker_init(parent: int) -> None:
    """The counting process: Ctrl-C is the parent's to handle (no traceback from here), and it ends when the
    parent is gone, however it ended (a killed parent closes no queue)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def captures_in(frames_dir: str | Path) -> int:
    """Captures saved so far (their pose files)."""
    try:
        return sum(1 for p in Path(frames_dir).iterdir() if p.suffix == ".json" and p.name != "surface.json")
    except OSError:
        return 0


class DefectTally:
    """Recounts ``frames_dir`` into ``view`` when it has new captures (a daemon thread and one worker process)."""

    def __init__(self, view: FleetView, frames_dir: str | Path, corners: Sequence[Sequence[float]] | None,
                 interval_s: float = INTERVAL_S):
        self.view, self.frames_dir, self.interval_s = view, str(frames_dir), float(interval_s)
        self.corners = None if corners is None else [tuple(float(x) for x in c) for c in corners]
        self.counts = 0  # counts finished
        self.errors = 0  # counts that could not read the folder (a capture being written): retried
        self._stop = threading.Event()
        self._poke = threading.Event()
        self._pool: ProcessPoolExecutor | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> DefectTally:
        self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=_worker_init, initargs=(os.getpid(),))
        self._thread = threading.Thread(target=self._run, name="web-tally", daemon=True)
        self._thread.start()
        return self

    def poke(self) -> None:
        """Count now if there are new captures (the mission's end, say), not after the interval."""
        self._poke.set()

    def _run(self) -> None:
        counted, last = -1, -float("inf")
        while not self._stop.is_set():
            self._poke.wait(1.0)
            poked = self._poke.is_set()
            self._poke.clear()
            n = captures_in(self.frames_dir)
            if n == counted or n == 0 or (not poked and time.monotonic() - last < self.interval_s):
                continue
            last = time.monotonic()
            if self._pool is None:
                return
            fut: Future = self._pool.submit(count_defects, self.frames_dir, self.corners)
            try:
                defects, frames = fut.result()
            except ValueError as exc:  # a capture half written: the next round reads it whole
                self.errors += 1
                log.debug("web: defect count deferred (%s)", exc)
                continue
            except Exception as exc:  # noqa: BLE001 - the worker died or the pool is shutting down
                if not self._stop.is_set():
                    self.errors += 1
                    log.warning("web: defect count failed: %s", exc)
                continue
            counted = n if frames >= n else frames
            self.counts += 1
            self.view.set_inspection(defects, frames)

    def stop(self) -> None:
        self._stop.set()
        self._poke.set()
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        if self._thread is not None:
            self._thread.join(10)
