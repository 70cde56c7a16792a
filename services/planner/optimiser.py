"""What every path optimiser shares: the result type and the budget / convergence bookkeeping.

Design notes: docs/planner.md (services/planner/optimiser.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["OptResult", "Tracker", "check_budget"]


@dataclass
class OptResult:
    """Outcome of one optimiser run: the best decision vector ``x`` (free waypoints, flattened), its cost (P5),
    the best cost after the initial population and each further ``particles`` evaluations, the
    evaluations used and the wall time."""

    algorithm: str
    x: NDArray[np.float64]
    cost: float
    history: NDArray[np.float64]
    evaluations: int
    wall_time_s: float

    @property
    def initial_cost(self) -> float:
        return float(self.history[0])

    def convergence_iteration(self, rel: float = 1e-3) -> int:
        """First iteration whose best cost is within ``rel`` (0.1 %) of the final cost."""
        h = self.history
        return int(np.argmax(h <= self.cost + rel * abs(self.cost)))


@dataclass
class Start:
    """What every optimiser begins with: the population (a copy of ``x0``), its size ``P``, the
    iteration count ``I``, the box bounds tiled over the waypoints, the tracker, and the
    population's costs already evaluated and recorded."""

    X: NDArray[np.float64]
    P: int
    I: int
    lo: NDArray[np.float64]
    hi: NDArray[np.float64]
    tracker: Tracker
    f: NDArray[np.float64]


def start(name: str, cost, x0, iterations: int) -> Start:
    """Check the budget, evaluate ``x0 (P, D)`` once and record it (budget ``P (I + 1)``)."""
    X = np.asarray(x0, float).copy()
    P, I = check_budget(X.shape[0], iterations)
    D = X.shape[1]
    lo = np.tile(cost.problem.lo, D // 3)
    hi = np.tile(cost.problem.hi, D // 3)
    tr = Tracker(name, P, P * (I + 1))
    f = cost(X)
    tr.record(X, f)
    return Start(X, P, I, lo, hi, tr, f)


def check_budget(particles: int, iterations: int) -> tuple[int, int]:
    if int(particles) != particles or particles < 2:
        raise ValueError(f"particles must be an integer >= 2, got {particles!r}")
    if int(iterations) != iterations or iterations < 1:
        raise ValueError(f"iterations must be a positive integer, got {iterations!r}")
    return int(particles), int(iterations)


@dataclass
class Tracker:
    """Best-so-far bookkeeping, one history point per ``particles`` evaluations."""

    name: str
    particles: int
    budget: int
    best_x: NDArray[np.float64] | None = None
    best_f: float = np.inf
    used: int = 0
    history: list[float] = field(default_factory=list)
    t0: float = field(default_factory=time.perf_counter)

    @property
    def remaining(self) -> int:
        return self.budget - self.used

    def record(self, X: NDArray[np.float64], f: NDArray[np.float64]) -> None:
        """Account for a batch of evaluated candidates (in order of evaluation)."""
        k = 0
        n = f.shape[0]
        while k < n:
            room = self.particles - (self.used % self.particles)
            chunk = slice(k, min(n, k + room))
            i = int(np.argmin(f[chunk])) + k
            if f[i] < self.best_f:
                self.best_f, self.best_x = float(f[i]), X[i].copy()
            self.used += chunk.stop - chunk.start
            if self.used % self.particles == 0:
                self.history.append(self.best_f)
            k = chunk.stop

    def result(self) -> OptResult:
        return OptResult(self.name, np.asarray(self.best_x, float), float(self.best_f), np.asarray(self.history, float),
                         self.used, time.perf_counter() - self.t0)
