"""Simulation clock: sim = (wall − epoch) × speed, shared by every process of a run."""

from __future__ import annotations

import math
import time

import pytest

from edge.clock import SimClock, new_epoch


class ManualTime:
    """A wall clock that only moves when slept on (deterministic time source)."""

    def __init__(self, t: float):
        self.t = t
        self.slept: list[float] = []

    def time(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += s


def test_speed_factor_scales_sim_time():
    w = ManualTime(1000.0)
    c = SimClock(epoch=990.0, speed=10.0, time_fn=w.time, sleep_fn=w.sleep)
    assert c.now() == pytest.approx(100.0)
    w.t += 2.0
    assert c.now() == pytest.approx(120.0)
    assert c.wall_of(150.0) == pytest.approx(1005.0)
    assert c.sim_of(c.wall_of(37.5)) == pytest.approx(37.5)


def test_shared_epoch_gives_same_time_to_all_processes():
    w = ManualTime(5000.0)
    epoch = new_epoch(3.0, time_fn=w.time)
    assert epoch == 5003.0
    a = SimClock(epoch, 4.0, time_fn=w.time, sleep_fn=w.sleep)
    b = SimClock(epoch, 4.0, time_fn=w.time, sleep_fn=w.sleep)
    assert a.now() == b.now() == pytest.approx(-12.0)  # before the epoch: negative
    assert a.sleep_until(0.0) == pytest.approx(0.0)
    assert w.t == pytest.approx(epoch)
    assert b.now() == pytest.approx(0.0)


def test_sleep_until_sleeps_wall_time_divided_by_speed():
    w = ManualTime(100.0)
    c = SimClock(100.0, speed=50.0, time_fn=w.time, sleep_fn=w.sleep)
    assert c.sleep_until(25.0) == pytest.approx(25.0)
    assert sum(w.slept) == pytest.approx(0.5)
    # in the past: no sleep
    n = len(w.slept)
    assert c.sleep_until(10.0) == pytest.approx(25.0)
    assert len(w.slept) == n


def test_default_epoch_is_now():
    w = ManualTime(777.0)
    c = SimClock(speed=2.0, time_fn=w.time, sleep_fn=w.sleep)
    assert c.epoch == 777.0 and c.now() == 0.0


def test_real_time_source_runs_forward():
    c = SimClock(time.time(), speed=1000.0)
    t1 = c.sleep_until(c.now() + 5.0)  # 5 ms of wall time
    assert t1 >= 5.0 - 1e-6


@pytest.mark.parametrize("epoch,speed", [(math.nan, 1.0), (0.0, 0.0), (0.0, -1.0), (-1.0, 1.0), (0.0, math.inf)])
def test_bad_arguments_raise(epoch, speed):
    with pytest.raises(ValueError):
        SimClock(epoch, speed)


def test_bad_times_raise():
    c = SimClock(0.0)
    with pytest.raises(ValueError):
        c.wall_of(math.nan)
    with pytest.raises(ValueError):
        new_epoch(-1.0)
