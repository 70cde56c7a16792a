"""Bounded work for the planner: limits checked before any work, and a time budget per request.

The cost (P5, :class:`services.planner.cost.Cost`) evaluates every particle, UAV, segment and
obstacle in whole-array numpy operations, so one evaluation of a swarm holds arrays of
``M x max(C, K) x S x P`` float64 (M UAVs, C obstacles, K = 8 wall samples, S = waypoints + 1
segments, P particles), and a whole run costs about that times the iterations. The schema's
largest request (10,000 particles x 100,000 iterations, 200 waypoints) is valid but would hold
the planner for hours and take gigabytes, so before planning:

- :data:`MAX_CELLS` bounds the largest cost array (4 M elements, 32 MB): the paper's budget
  (150 particles, 10 waypoints, 3 UAVs, 10 cylinders) needs 49,500;
- :data:`MAX_WORK` bounds cells x iterations (5e8, about 50 s here; the paper's is 1.5e7, 1.6 s);

and a request over either is refused at once (:class:`TooLarge`, the reply says which limit and
by how much). While planning, :class:`Deadline` wraps the cost and ends the optimiser when the
request's time budget (:data:`TIME_BUDGET_S`, ``skynet planner --time-budget-s``) is spent
(:class:`TimeBudgetExceeded`), so a worker is never held past it.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

#: largest cost array, elements (M x max(C, K) x S x P)
MAX_CELLS = 4_000_000
#: cells x iterations of one request
MAX_WORK = 500_000_000
#: default time budget of one plan request, s (under the ground station's 120 s plan timeout)
TIME_BUDGET_S = 60.0
#: wall samples per UAV segment in the cost (services.planner.cost.Cost.SAMPLES)
WALL_SAMPLES = 8


class TooLarge(ValueError):
    """A plan request over the planner's limits (refused before any work)."""


class TimeBudgetExceeded(ValueError):
    """The request's time budget ran out while planning."""


def work_of(uavs: int, obstacles: int, particles: int, iterations: int, waypoints: int) -> tuple[int, int]:
    """``(cells, work)`` of a request: its largest cost array and cells x iterations."""
    cells = uavs * max(obstacles, WALL_SAMPLES) * (waypoints + 1) * particles
    return cells, cells * iterations


def check_budget(uavs: int, obstacles: int, particles: int, iterations: int, waypoints: int) -> None:
    """:class:`TooLarge` when the request is over :data:`MAX_CELLS` or :data:`MAX_WORK`."""
    cells, work = work_of(uavs, obstacles, particles, iterations, waypoints)
    what = (f"{particles} particles x {iterations} iterations x {waypoints} waypoints for {uavs} UAVs and "
            f"{obstacles} obstacles")
    if cells > MAX_CELLS:
        raise TooLarge(f"too large: {what} needs cost arrays of {cells:,} elements (limit {MAX_CELLS:,}); "
                       "use fewer particles or waypoints")
    if work > MAX_WORK:
        raise TooLarge(f"too large: {what} is {work:.2e} units of work (limit {MAX_WORK:.0e}, about "
                       f"{work / MAX_WORK:.0f}x over); use fewer particles or iterations")


class Deadline:
    """A cost function that raises :class:`TimeBudgetExceeded` once ``budget_s`` from now has passed.

    Every optimiser calls the cost once per iteration on its swarm, so the run ends within one
    iteration of the deadline; other attributes are the wrapped cost's."""

    def __init__(self, cost: Any, budget_s: float):
        if not budget_s > 0:
            raise ValueError(f"time budget must be > 0 s, got {budget_s!r}")
        self._cost, self.budget_s = cost, budget_s
        self.deadline = time.monotonic() + budget_s
        #: the best decision vector evaluated so far and its cost, and the best cost after each call
        #: (what an anytime answer is made of: services.planner.mission.optimise(anytime=True))
        self.best_x: Any = None
        self.best_cost = float("inf")
        self.history: list[float] = []

    def __call__(self, x):
        if time.monotonic() > self.deadline:
            raise TimeBudgetExceeded(f"the plan's time budget of {self.budget_s:g} s ran out "
                                     f"after {self._cost.evaluations:,} evaluations")
        costs = self._cost(x)
        i = int(np.argmin(costs))
        if costs[i] < self.best_cost:
            self.best_cost, self.best_x = float(costs[i]), np.array(np.asarray(x)[i], float)
        self.history.append(self.best_cost)
        return costs

    def __getattr__(self, name: str) -> Any:
        return getattr(self._cost, name)
