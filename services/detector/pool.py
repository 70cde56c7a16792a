"""Detection in worker processes: a process pool that survives its workers ("a detector that scales").

Design notes: docs/detector.md (services/detector/pool.py).
"""

from __future__ import annotations

import hashlib
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from protocol.messages import DefectReport, FrameEvidence, ImageMeta

#: start methods that do not fork the parent's threads (Zenoh runs its own)
CONTEXTS = ("spawn", "forkserver")
#: OpenCV threads per worker process. OpenCV's default is one per core in every process, so two workers on
#: two cores ran four threads, and a parallel ``cv2.dnn`` forward waits at each layer for its slowest thread:
#: on a loaded machine that thread is often descheduled (the learned method's 640 x 480 forward took 100 ms
#: on two threads against 77 ms CPU on one, docs/detector.md "Speed"). The pool's parallelism is its workers.
THREADS_PER_WORKER = 1


class WorkerCrashed(RuntimeError):
    """A job broke its worker process twice (once on the old pool, once on a fresh one)."""


def analyse_frame(meta: ImageMeta, image: bytes, method: str, ssrc: int, seq: int,
                  max_pixels: int | None = None) -> DefectReport:
    """One frame in a worker: decode, detect, map (:func:`~services.detector.pipeline.analyse`), and the
    frame evidence the ground station checks (:mod:`services.gcs.evidence`: SSRC, RTP sequence number,
    SHA-256 of the image bytes)."""
    from .pipeline import analyse

    report = analyse(meta, image, method, max_pixels=max_pixels)
    return report.model_copy(update={"frame": FrameEvidence(ssrc=ssrc, seq=seq,
                                                            digest=hashlib.sha256(image).hexdigest())})


def _init_worker(threads: int = THREADS_PER_WORKER) -> None:
    """A worker ignores Ctrl-C: the signal goes to the whole process group, and the detector that owns the
    pool shuts it down itself (:meth:`DetectorPool.close`) after draining its queue. A worker whose detector
    dies without closing it (SIGKILL, a crash) follows it at once instead of staying behind as an orphan.
    Its OpenCV runs ``threads`` threads (:data:`THREADS_PER_WORKER`)."""
    import cv2

    cv2.setNumThreads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent = multiprocessing.parent_process()
    if parent is not None:
        def follow() -> None:
            parent.join()  # returns when the parent's sentinel closes: it has ended
            os._exit(0)

        threading.Thread(target=follow, name="follow-parent", daemon=True).start()


def _warm(method: str = "it+r") -> int:
    """Import the detection stack in a fresh worker (spawn imports lazily) and analyse one small frame of a
    crack with ``method``, so the first capture is not slow: the crack's skeleton imports scikit-image's
    morphology on first use (services.detector.measure), 0.5-1 s that the first frame of each worker paid
    (the p95 of a 26-frame mission with two workers was those two frames); the learned method reads its
    model here, once per worker (a bad model file raises its one-line error to :meth:`DetectorPool.warm`)."""
    import cv2
    import numpy as np

    from protocol.messages import ImageMeta, Intrinsics

    from .pipeline import analyse

    grey = np.full((96, 128), 160, np.uint8)
    cv2.line(grey, (10, 20), (118, 76), 60, 3)
    jpeg = cv2.imencode(".jpg", grey)[1].tobytes()
    meta = ImageMeta(uav=1, capture_id=0, t=0.0, stamp=0.0, cam_pos=(0.0, 0.0, 0.0), cam_rot=(1, 0, 0, 0, 1, 0, 0, 0, 1),
                     intrinsics=Intrinsics(width=128, height=96, fx=100.0, fy=100.0, cx=64.0, cy=48.0), range_m=1.0)
    analyse(meta, jpeg, method)
    if method == "learned":  # the runtime's kernels for the frame sizes the cameras send
        from .learned import warm_up

        warm_up()
    time.sleep(0.2)  # best effort: hold this worker, so that each of the pool's warm calls lands on another one
    return os.getpid()


def worker_threads() -> int:
    """OpenCV's thread count in the calling process (in a worker: :data:`THREADS_PER_WORKER` unless set)."""
    import cv2

    return int(cv2.getNumThreads())


class DetectorPool:
    """``workers`` detection processes; :meth:`analyse` blocks its (Ring worker) thread for one frame."""

    def __init__(self, workers: int = 2, context: str = "spawn", max_pixels: int | None = None,
                 threads: int = THREADS_PER_WORKER):
        self.max_pixels = max_pixels  # frames above it are detected on a reduced decode (pipeline.analyse)
        if workers < 1:
            raise ValueError("the pool needs at least one worker process")
        if threads < 1:
            raise ValueError("each worker needs at least one OpenCV thread")
        self.threads = threads
        if context not in CONTEXTS:
            raise ValueError(f"start method {context!r}: choose from {CONTEXTS}")
        self.workers = workers
        self._ctx = multiprocessing.get_context(context)
        self._lock = threading.Lock()
        self._closed = False
        self.crashes = 0  # executors replaced after a worker died
        self.given_up = 0  # jobs that broke a fresh worker too
        self._generation = 0
        self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(max_workers=self.workers, mp_context=self._ctx, initializer=_init_worker,
                                   initargs=(self.threads,))

    def warm(self, timeout: float = 60.0, method: str = "it+r") -> list[int]:
        """Start every worker process and import the detection stack (and ``method``'s model) in it; their pids."""
        with self._lock:
            pool = self._pool
        futs = [pool.submit(_warm, method) for _ in range(self.workers)]
        return [f.result(timeout) for f in futs]

    def call(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` in a worker process (``fn`` and the arguments must pickle); see docs/detector.md
        for what a crash does. Exceptions raised by ``fn`` come back as they are."""
        for attempt in (1, 2):
            with self._lock:
                if self._closed:
                    raise RuntimeError("the detector pool is closed")
                pool, generation = self._pool, self._generation
            try:
                return pool.submit(fn, *args).result()
            except BrokenProcessPool:
                self._replace(generation)
                if attempt == 2:
                    with self._lock:
                        self.given_up += 1
                    raise WorkerCrashed("the frame broke a detection worker twice") from None
        raise AssertionError("unreachable")

    def analyse(self, meta: ImageMeta, image: bytes, method: str, ssrc: int, seq: int) -> DefectReport:
        """:func:`analyse_frame` in a worker process."""
        return self.call(analyse_frame, meta, bytes(image), method, ssrc, seq, self.max_pixels)

    def _replace(self, generation: int) -> None:
        """Replace a broken executor once, however many threads saw it break."""
        with self._lock:
            if self._closed or generation != self._generation:
                return  # another thread has replaced it already
            broken, self._pool = self._pool, self._new_pool()
            self._generation += 1
            self.crashes += 1
        broken.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            pool = self._pool
        pool.shutdown(wait=True, cancel_futures=True)
