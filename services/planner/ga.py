"""Real-coded genetic algorithm, the GA baseline of Table I (cf. Pehlivanoglu 2012).

Design notes: docs/planner.md (services/planner/ga.py).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .cost import Cost
from .optimiser import OptResult, start

__all__ = ["ga"]


def ga(cost: Cost, x0: ArrayLike, iterations: int, rng: np.random.Generator, crossover: float = 0.9, alpha: float = 0.5,
       sigma: tuple[float, float] = (0.1, 0.01)) -> OptResult:
    """Minimise ``cost`` with a (μ + λ) real-coded GA from ``x0 (P, D)``."""
    st = start("ga", cost, x0, iterations)
    X, P, I, lo, hi, tr, f = st.X, st.P, st.I, st.lo, st.hi, st.tracker, st.f
    D = X.shape[1]
    for k in range(I):
        a, b = rng.integers(0, P, (2, P)), rng.integers(0, P, (2, P))
        pa = np.where(f[a[0]] < f[a[1]], a[0], a[1])
        pb = np.where(f[b[0]] < f[b[1]], b[0], b[1])
        A, B = X[pa], X[pb]
        mn, mx = np.minimum(A, B), np.maximum(A, B)
        span = mx - mn
        child = rng.uniform(mn - alpha * span, mx + alpha * span)
        keep = rng.random((P, 1)) >= crossover
        child = np.where(keep, A, child)
        s = sigma[0] + (sigma[1] - sigma[0]) * k / max(I - 1, 1)
        mut = rng.random((P, D)) < 1.0 / D
        child = child + mut * rng.normal(0.0, 1.0, (P, D)) * s * (hi - lo)
        child = np.clip(child, lo, hi)
        fc = cost(child)
        tr.record(child, fc)
        allX, allf = np.concatenate([X, child]), np.concatenate([f, fc])
        idx = np.argsort(allf, kind="stable")[:P]
        X, f = allX[idx], allf[idx]
    return tr.result()
