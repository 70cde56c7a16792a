"""Teaching-learning-based optimisation, the TLBO baseline of Table I (Rao et al. 2011).

Design notes: docs/planner.md (services/planner/tlbo.py).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .cost import Cost
from .optimiser import OptResult, start

__all__ = ["tlbo"]


def tlbo(cost: Cost, x0: ArrayLike, iterations: int, rng: np.random.Generator) -> OptResult:
    """Minimise ``cost`` with TLBO from ``x0 (P, D)`` within ``P (iterations + 1)`` evaluations."""
    s = start("tlbo", cost, x0, iterations)
    X, P, lo, hi, tr, f = s.X, s.P, s.lo, s.hi, s.tracker, s.f
    D = X.shape[1]
    phase = 0
    while tr.remaining >= P:
        if phase == 0:  # teacher phase
            teacher = X[int(np.argmin(f))]
            tf = rng.integers(1, 3, (P, 1))
            Y = X + rng.random((P, D)) * (teacher - tf * X.mean(axis=0))
        else:  # learner phase
            j = (np.arange(P) + rng.integers(1, P, P)) % P  # a partner != i
            sgn = np.where(f < f[j], 1.0, -1.0)[:, None]
            Y = X + rng.random((P, D)) * sgn * (X - X[j])
        Y = np.clip(Y, lo, hi)
        fy = cost(Y)
        tr.record(Y, fy)
        better = fy < f
        X[better], f[better] = Y[better], fy[better]
        phase ^= 1
    return tr.result()
