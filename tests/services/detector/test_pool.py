"""services.detector.pool: detection in real worker processes; a dead worker is counted and replaced."""

import os
import time

import cv2
import numpy as np
import pytest

from edge.world.surface import crack_image
from protocol.messages import ImageMeta, Intrinsics
from protocol.rtp import ssrc_for
from services.detector.pipeline import analyse
from services.detector.pool import THREADS_PER_WORKER, DetectorPool, WorkerCrashed, worker_threads


def _frame(seed):
    grey, _ = crack_image((240, 320), np.random.default_rng(seed), n_cracks=2)
    meta = ImageMeta(uav=3, capture_id=seed, t=0.0, stamp=time.time(), cam_pos=(10.0, 0.0, 20.0),
                     cam_rot=(1, 0, 0, 0, 0, 1, 0, -1, 0),
                     intrinsics=Intrinsics(width=320, height=240, fx=500, fy=500, cx=160, cy=120), range_m=5.0)
    return meta, cv2.imencode(".jpg", grey)[1].tobytes()


def _die():
    os._exit(7)


def _boom():
    raise ZeroDivisionError("in the worker")


@pytest.fixture
def pool():
    p = DetectorPool(2)
    yield p
    p.close()


def test_reports_come_from_other_processes_with_the_frame_evidence(pool):
    pids = pool.warm()
    assert len(set(pids)) == 2 and os.getpid() not in pids
    meta, jpeg = _frame(1)
    r = pool.analyse(meta, jpeg, "it+", ssrc_for(3), 41)
    local = analyse(meta, jpeg, "it+")
    assert r.ok and r.defects and [d.bbox for d in r.defects] == [d.bbox for d in local.defects]
    assert r.frame.ssrc == ssrc_for(3) and r.frame.seq == 41
    import hashlib
    assert r.frame.digest == hashlib.sha256(jpeg).hexdigest()
    bad = pool.analyse(meta, b"\xff\xd8 not a jpeg", "it+", ssrc_for(3), 42)
    assert not bad.ok and bad.frame.seq == 42


def test_a_dead_worker_is_counted_and_the_pool_recovers(pool):
    pool.warm()
    with pytest.raises(WorkerCrashed):
        pool.call(_die)  # kills its worker on the old pool, and again on the fresh one: given up
    assert pool.crashes == 2 and pool.given_up == 1
    meta, jpeg = _frame(2)
    assert pool.analyse(meta, jpeg, "it+", ssrc_for(3), 1).ok  # served by a fresh pool
    with pytest.raises(ZeroDivisionError):  # an ordinary exception is the caller's, not a crash
        pool.call(_boom)
    assert pool.crashes == 2


def test_a_worker_killed_from_outside_costs_no_frame(pool):
    pids = pool.warm()
    import signal
    os.kill(pids[0], signal.SIGKILL)
    time.sleep(0.5)
    meta, jpeg = _frame(3)
    r = pool.analyse(meta, jpeg, "it+", ssrc_for(3), 5)  # the broken pool is replaced, the frame run again
    assert r.ok and pool.crashes == 1 and pool.given_up == 0


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError):
        DetectorPool(0)
    with pytest.raises(ValueError, match="thread"):
        DetectorPool(1, threads=0)
    with pytest.raises(ValueError, match="start method"):
        DetectorPool(1, "fork")


def test_workers_follow_a_detector_killed_without_closing_its_pool():
    """A detector that is SIGKILLed (a fault, the OOM killer) leaves no worker processes behind."""
    import signal
    import subprocess
    import sys

    from tests.conftest import wait_until

    code = ("from services.detector.pool import DetectorPool\n"
            "import time\n"
            "p = DetectorPool(2)\n"
            "print(*p.warm(), flush=True)\n"
            "time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        pids = [int(x) for x in proc.stdout.readline().split()]
        assert len(pids) == 2 and all(_alive(p) for p in pids)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        assert wait_until(lambda: not any(_alive(p) for p in pids), 10), pids
    finally:
        proc.kill()
        proc.wait()


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"  # a zombie has ended
    except FileNotFoundError:
        return False


def test_each_worker_runs_opencv_on_one_thread_not_one_per_core(pool):
    """Two workers each running OpenCV's default (a thread per core) oversubscribe the cores."""
    assert THREADS_PER_WORKER == 1
    assert pool.call(worker_threads) == 1
    assert pool.warm() and pool.call(worker_threads) == 1  # after a frame, too
    p = DetectorPool(1, threads=2)
    try:
        assert p.call(worker_threads) == 2
    finally:
        p.close()
