"""Attitude control: adaptive twisting sliding-mode control (ATSM), PAPER.md (P13)-(P17).

Design notes: docs/edge.md (edge/vehicle/atsm.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .angles import wrap_angle

__all__ = ["ATSMGains", "ATSM", "TwistingController"]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class ATSMGains:
    """Gains of the ATSM controller per axis (roll, pitch, yaw): ``lam`` Λ of (P14) (1/s), ``mu`` μ of (P16)
    in (0, 1), ``alpha0`` the initial (or :class:`TwistingController`'s fixed) twisting gain α, ``alpha_m``
    the floor and ``alpha_max`` the clamp of α (N·m), ``omega_bar`` ω̄, ``rho`` ρ, ``eps`` ε and ``eta`` η of (P17)."""

    lam: Vec3 = (8.0, 8.0, 7.0)
    mu: Vec3 = (0.5, 0.5, 0.5)
    alpha0: Vec3 = (0.15, 0.15, 0.10)
    alpha_m: Vec3 = (0.06, 0.06, 0.03)
    alpha_max: Vec3 = (0.6, 0.6, 0.48)
    omega_bar: Vec3 = (30.0, 30.0, 90.0)
    rho: Vec3 = (0.5, 0.5, 0.5)
    eps: Vec3 = (0.2, 0.2, 0.2)
    eta: Vec3 = (0.1, 0.1, 0.1)

    def __post_init__(self) -> None:
        for name in ("lam", "mu", "alpha0", "alpha_m", "alpha_max", "omega_bar", "rho", "eps", "eta"):
            v = getattr(self, name)
            if len(v) != 3 or not all(math.isfinite(x) and x > 0 for x in v):
                raise ValueError(f"ATSM gain {name} must be 3 finite positive numbers")
        if not all(m < 1 for m in self.mu):
            raise ValueError("twisting mu must be in (0, 1)")
        if not all(lo <= hi for lo, hi in zip(self.alpha_m, self.alpha_max)):
            raise ValueError("alpha_m must not exceed alpha_max")


class ATSM:
    """Adaptive twisting sliding-mode attitude controller (P13)-(P17) with a model ``inertia`` (may differ
    from the plant's), period ``dt``; ``adaptive`` False is the fixed-gain twisting controller."""

    def __init__(self, inertia: Vec3, gains: ATSMGains = ATSMGains(), dt: float = 1 / 200, adaptive: bool = True):
        inertia = tuple(float(v) for v in inertia)
        if len(inertia) != 3 or not all(math.isfinite(v) and v > 0 for v in inertia):
            raise ValueError("inertia must be 3 finite positive numbers")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError("dt must be finite and > 0")
        self.inertia = inertia
        self.gains = gains
        self.dt = float(dt)
        self.adaptive = bool(adaptive)
        self.reset()

    def reset(self) -> None:
        """Forget σ history and restart the gains at α0."""
        self.alpha = list(self.gains.alpha0)
        self._sigma_prev: list[float] | None = None
        self.sigma: Vec3 = (0.0, 0.0, 0.0)

    def update(self, att: Vec3, datt: Vec3, rates: Vec3, ref: Vec3, dref: Vec3 = (0.0, 0.0, 0.0),
               ddref: Vec3 = (0.0, 0.0, 0.0)) -> Vec3:
        """One control period: torques ``u = u_eq + u_T`` (P13), N·m, from Θ, Θ̇, the body rates (for f(X) of
        (P12)) and the reference Θ_d with its first two derivatives."""
        ixx, iyy, izz = self.inertia
        p, q, r = rates
        # f(X) of (P12) with the model inertia
        f = ((iyy - izz) * q * r, (izz - ixx) * p * r, (ixx - iyy) * p * q)
        g = self.gains
        lam, mu = g.lam, g.mu
        e = (att[0] - ref[0], att[1] - ref[1], wrap_angle(att[2] - ref[2]))
        de = (datt[0] - dref[0], datt[1] - dref[1], datt[2] - dref[2])
        sigma = [de[i] + lam[i] * e[i] for i in range(3)]  # (P14)
        prev = self._sigma_prev if self._sigma_prev is not None else sigma
        alpha = self.alpha
        inv_dt = 1.0 / self.dt
        inertia = self.inertia
        u = [0.0, 0.0, 0.0]
        for i in range(3):
            s = sigma[i]
            ds = (s - prev[i]) * inv_dt
            a = alpha[i]
            sgn = 1.0 if s > 0.0 else (-1.0 if s < 0.0 else 0.0)
            u_t = -(mu[i] * a if s * ds <= 0.0 else a) * sgn  # (P16)
            u_eq = inertia[i] * (ddref[i] - lam[i] * de[i]) - f[i]  # (P15)
            u[i] = u_eq + u_t  # (P13)
            if self.adaptive:  # (P17)
                abs_s = abs(s)
                if a > g.alpha_m[i]:
                    da = g.omega_bar[i] * abs_s * (1.0 if abs_s ** g.rho[i] > g.eps[i] else -1.0)
                else:
                    da = g.eta[i]
                a += da * self.dt
                alpha[i] = min(a, g.alpha_max[i])
        self._sigma_prev = sigma
        self.sigma = (sigma[0], sigma[1], sigma[2])
        return (u[0], u[1], u[2])


class TwistingController(ATSM):
    """Fixed-gain twisting sliding-mode controller: (P13)-(P16) with α = α0, no (P17)."""

    def __init__(self, inertia: Vec3, gains: ATSMGains = ATSMGains(), dt: float = 1 / 200):
        super().__init__(inertia, gains, dt, adaptive=False)
