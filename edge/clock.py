"""Simulation clock shared by every process of a run.

Design notes: docs/edge.md (edge/clock.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

__all__ = ["SimClock", "new_epoch"]


def new_epoch(delay_s: float = 0.0, *, time_fn: Callable[[], float] = time.time) -> float:
    """A run's epoch: the wall-clock UNIX time ``delay_s`` seconds from now.

    A small positive delay lets every process start up before simulated time 0.
    """
    if not (math.isfinite(delay_s) and delay_s >= 0):
        raise ValueError("delay_s must be finite and >= 0")
    return time_fn() + delay_s


class SimClock:
    """``sim = (wall − epoch) × speed``: ``epoch`` the UNIX time of simulated time 0 shared by a run's
    processes (None: now), ``speed`` > 0; ``time_fn``/``sleep_fn`` default to :func:`time.time`/:func:`time.sleep`."""

    def __init__(self, epoch: float | None = None, speed: float = 1.0, *, time_fn: Callable[[], float] = time.time,
                 sleep_fn: Callable[[float], None] = time.sleep):
        epoch = float(time_fn() if epoch is None else epoch)
        speed = float(speed)
        if not (math.isfinite(epoch) and epoch >= 0):
            raise ValueError("epoch must be a finite UNIX time >= 0")
        if not (math.isfinite(speed) and 0 < speed <= 1e6):
            raise ValueError("speed must be finite and in (0, 1e6]")
        self.epoch = epoch
        self.speed = speed
        self._time = time_fn
        self._sleep = sleep_fn

    def now(self) -> float:
        """Current simulated time, s (negative before the epoch)."""
        return (self._time() - self.epoch) * self.speed

    def wall_of(self, t_sim: float) -> float:
        """Wall-clock UNIX time at which simulated time ``t_sim`` occurs."""
        if not math.isfinite(t_sim):
            raise ValueError("t_sim must be finite")
        return self.epoch + t_sim / self.speed

    def sim_of(self, wall: float) -> float:
        """Simulated time at wall-clock UNIX time ``wall`` (e.g. a message's ``t0_stamp``)."""
        if not math.isfinite(wall):
            raise ValueError("wall must be finite")
        return (wall - self.epoch) * self.speed

    def sleep_until(self, t_sim: float) -> float:
        """Sleep until simulated time ``t_sim`` (no-op if already past); returns :meth:`now`."""
        target = self.wall_of(t_sim)
        while True:
            remaining = target - self._time()
            if remaining <= 0:
                return self.now()
            self._sleep(remaining)

    def __repr__(self) -> str:
        return f"SimClock(epoch={self.epoch!r}, speed={self.speed!r})"
