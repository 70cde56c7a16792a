"""Angle-encoded particle swarm optimisation, θ-PSO (P4) (Hoang et al. 2018, the paper's Section 3).

Design notes: docs/planner.md (services/planner/theta_pso.py).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .cost import Cost
from .optimiser import OptResult, start

__all__ = ["sine_map", "inverse_sine_map", "theta_pso"]

HALF_PI = 0.5 * np.pi


def sine_map(theta: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.float64]:
    """``x = 1/2 [(x_max − x_min) sin θ + x_max + x_min]`` (P4); maps [−π/2, π/2] onto [lo, hi]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return 0.5 * ((hi - lo) * np.sin(theta) + hi + lo)


def inverse_sine_map(x: ArrayLike, lo: ArrayLike, hi: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`sine_map` on [lo, hi] (values outside are clipped), in [−π/2, π/2]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    u = (2.0 * np.asarray(x, float) - hi - lo) / (hi - lo)
    return np.arcsin(np.clip(u, -1.0, 1.0))


def theta_pso(cost: Cost, x0: ArrayLike, iterations: int, rng: np.random.Generator, w: tuple[float, float] = (0.7, 0.3),
              c1: float = 2.0, c2: float = 2.0, per_dimension: bool = True, dtheta_max: float = 0.1) -> OptResult:
    """Minimise ``cost`` with θ-PSO (P4) from the initial population ``x0 (P, D)`` (θ from its inverse sine
    map, Δθ 0); budget ``P (iterations + 1)``. Inertia ``w`` linear from start to end, gains ``c1``, ``c2``,
    ``r1, r2`` per particle and dimension unless ``per_dimension`` is False, ``|Δθ| <= dtheta_max <= π/2``."""
    if not 0.0 < dtheta_max <= HALF_PI:
        raise ValueError(f"dtheta_max must be in (0, π/2], got {dtheta_max!r}")
    # the shared initial population is evaluated itself (sine_map(theta) equals it to rounding)
    s = start("theta-pso", cost, x0, iterations)
    X, P, I, lo, hi, tr, f = s.X, s.P, s.I, s.lo, s.hi, s.tracker, s.f
    D = X.shape[1]
    mid, half = 0.5 * (hi + lo), 0.5 * (hi - lo)  # sine map (P4): x = mid + half sin θ
    theta = inverse_sine_map(X, lo, hi)
    dtheta = np.zeros_like(theta)
    pbest, pbest_f = theta.copy(), f.copy()
    g = int(np.argmin(f))
    rshape = (P, D) if per_dimension else (P, 1)
    x = np.empty_like(theta)
    tmp = np.empty_like(theta)
    for k in range(I):
        wk = w[0] + (w[1] - w[0]) * k / max(I - 1, 1)
        r1 = rng.random(rshape)
        r2 = rng.random(rshape)
        dtheta *= wk
        np.subtract(pbest, theta, out=tmp)
        tmp *= c1 * r1
        dtheta += tmp
        np.subtract(pbest[g], theta, out=tmp)
        tmp *= c2 * r2
        dtheta += tmp
        np.clip(dtheta, -dtheta_max, dtheta_max, out=dtheta)
        theta += dtheta
        np.clip(theta, -HALF_PI, HALF_PI, out=theta)
        np.sin(theta, out=x)
        x *= half
        x += mid
        f = cost(x)
        tr.record(x, f)
        better = f < pbest_f
        pbest[better], pbest_f[better] = theta[better], f[better]
        g = int(np.argmin(pbest_f))
    return tr.result()
