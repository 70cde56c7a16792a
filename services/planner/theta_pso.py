"""Angle-encoded particle swarm optimisation, θ-PSO (P4) (Hoang et al. 2018, PAPER.md Section 3).

Each particle carries phase angles θ and increments Δθ in ``[-π/2, π/2]``; per iteration k::

    Δθ_ij ← w Δθ_ij + c1 r1_i (λ_ij − θ_ij) + c2 r2_i (λ_gj − θ_ij)     (clipped to [−π/2, π/2])
    θ_ij  ← θ_ij + Δθ_ij                                                (clipped to [−π/2, π/2])
    x_ij  = 1/2 [ (x_max − x_min) sin θ_ij + x_max + x_min ]

with λ_i the personal and λ_g the global best (in θ), ``r1, r2 ~ U(0, 1)`` drawn once per
particle per iteration (the paper writes them ``r_{1i}^k``, scalars per particle; ``per_dimension=True`` draws
one per dimension instead). Our choices
(the paper gives no values): inertia ``w`` falling linearly from 0.9 to 0.4 over the iterations
(Shi & Eberhart 1998), ``c1 = c2 = 2.0`` (picked over 1.5 and the constriction
setting 0.729/1.49 on the monorail scenario: fewer seeds stall in a far local minimum), Δθ starting at zero, θ from the inverse sine map of the
shared initial population, so θ-PSO starts exactly where the other algorithms start.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .cost import Cost
from .optimiser import OptResult, Tracker, check_budget

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


def theta_pso(
    cost: Cost,
    x0: ArrayLike,
    iterations: int,
    rng: np.random.Generator,
    w: tuple[float, float] = (0.9, 0.4),
    c1: float = 2.0,
    c2: float = 2.0,
    per_dimension: bool = False,
) -> OptResult:
    """Minimise ``cost`` with θ-PSO (P4) from the initial population ``x0 (P, D)``.

    Parameters
    ----------
    cost : Cost
        Vectorised cost; its problem's box gives ``x_min``/``x_max``.
    x0 : array_like (P, D)
        Initial positions (shared by all algorithms).
    iterations : int
        Swarm iterations; budget ``P (iterations + 1)`` evaluations.
    rng : numpy.random.Generator
    w : (w_start, w_end)
        Linearly decreasing inertia weight.
    c1, c2 : float
        Cognitive and social gains.
    """
    X = np.asarray(x0, float)
    P, I = check_budget(X.shape[0], iterations)
    D = X.shape[1]
    lo = np.tile(cost.problem.lo, D // 3)
    hi = np.tile(cost.problem.hi, D // 3)
    tr = Tracker("theta-pso", P, P * (I + 1))
    theta = inverse_sine_map(X, lo, hi)
    dtheta = np.zeros_like(theta)
    f = cost(X)  # the shared initial population itself (sine_map(theta) equals it to rounding)
    tr.record(X, f)
    pbest, pbest_f = theta.copy(), f.copy()
    g = int(np.argmin(f))
    rshape = (P, D) if per_dimension else (P, 1)
    for k in range(I):
        wk = w[0] + (w[1] - w[0]) * k / max(I - 1, 1)
        r1 = rng.random(rshape)
        r2 = rng.random(rshape)
        dtheta = wk * dtheta + c1 * r1 * (pbest - theta) + c2 * r2 * (pbest[g] - theta)
        np.clip(dtheta, -HALF_PI, HALF_PI, out=dtheta)
        theta = np.clip(theta + dtheta, -HALF_PI, HALF_PI)
        x = sine_map(theta, lo, hi)
        f = cost(x)
        tr.record(x, f)
        better = f < pbest_f
        pbest[better], pbest_f[better] = theta[better], f[better]
        g = int(np.argmin(pbest_f))
    return tr.result()
