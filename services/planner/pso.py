"""Conventional global-best PSO (Kennedy & Eberhart 1995; Shi & Eberhart 1998) on the box.

Design notes: docs/planner.md (services/planner/pso.py).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .cost import Cost
from .optimiser import OptResult, start

__all__ = ["pso"]


def pso(cost: Cost, x0: ArrayLike, iterations: int, rng: np.random.Generator, w: tuple[float, float] = (0.7, 0.3),
        c1: float = 2.0, c2: float = 2.0, per_dimension: bool = True, vmax_fraction: float = 0.05) -> OptResult:
    """Minimise ``cost`` with gbest PSO from ``x0 (P, D)``; budget ``P (iterations + 1)``."""
    if not 0.0 < vmax_fraction <= 1.0:
        raise ValueError("vmax_fraction must be in (0, 1]")
    s = start("pso", cost, x0, iterations)
    X, P, I, lo, hi, tr, f = s.X, s.P, s.I, s.lo, s.hi, s.tracker, s.f
    D = X.shape[1]
    vmax = vmax_fraction * (hi - lo)
    V = np.zeros_like(X)
    pbest, pbest_f = X.copy(), f.copy()
    g = int(np.argmin(f))
    rshape = (P, D) if per_dimension else (P, 1)
    for k in range(I):
        wk = w[0] + (w[1] - w[0]) * k / max(I - 1, 1)
        r1 = rng.random(rshape)
        r2 = rng.random(rshape)
        V = wk * V + c1 * r1 * (pbest - X) + c2 * r2 * (pbest[g] - X)
        V = np.clip(V, -vmax, vmax)
        X = np.clip(X + V, lo, hi)
        f = cost(X)
        tr.record(X, f)
        better = f < pbest_f
        pbest[better], pbest_f[better] = X[better], f[better]
        g = int(np.argmin(pbest_f))
    return tr.result()
