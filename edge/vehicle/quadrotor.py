"""6-DoF quadcopter plant: rigid-body dynamics, actuator limits and a seeded disturbance model.

Design notes: docs/edge.md (edge/vehicle/quadrotor.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "GRAVITY", "QuadParams", "DisturbanceParams", "Disturbance", "Quadrotor", "body_rates_from_euler_rates",
    "euler_rates_from_body_rates"
]

GRAVITY = 9.81


@dataclass(frozen=True)
class QuadParams:
    """Physical parameters of the quadcopter (3DR Solo class defaults), SI units: mass, principal moments
    of inertia (P11), thrust-to-weight ratio, roll/pitch/yaw torque limits, linear drag coefficients,
    first-order actuator time constant (0: no lag) and gravity."""

    mass: float = 1.47
    ixx: float = 0.011
    iyy: float = 0.015
    izz: float = 0.021
    thrust_to_weight: float = 2.0
    torque_max: tuple[float, float, float] = (2.0, 2.0, 0.5)
    drag_xy: float = 0.30
    drag_z: float = 0.40
    motor_tau: float = 0.02
    g: float = GRAVITY

    def __post_init__(self) -> None:
        vals = (self.mass, self.ixx, self.iyy, self.izz, self.thrust_to_weight, *self.torque_max, self.g)
        if not all(math.isfinite(v) and v > 0 for v in vals):
            raise ValueError("mass, inertias, thrust_to_weight, torque limits and g must be finite and > 0")
        if self.thrust_to_weight <= 1.0:
            raise ValueError("thrust_to_weight must exceed 1 or the vehicle cannot hover")
        for v in (self.drag_xy, self.drag_z, self.motor_tau):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError("drag coefficients and motor_tau must be finite and >= 0")

    @property
    def thrust_max(self) -> float:
        """Maximum total thrust, N."""
        return self.thrust_to_weight * self.mass * self.g

    @property
    def hover_thrust(self) -> float:
        """Thrust that balances gravity, N."""
        return self.mass * self.g


@dataclass(frozen=True)
class DisturbanceParams:
    """Bounded disturbance model: torques d of (P11) and Ornstein-Uhlenbeck wind gusts (docs/edge.md,
    edge/vehicle/quadrotor.py)."""

    torque_amp: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque_freq_hz: tuple[float, float] = (0.2, 2.0)
    torque_tau: float = 0.3
    wind_mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_tau: float = 2.0
    gust_bound: float = 6.0

    def __post_init__(self) -> None:
        vals = (*self.torque_amp, *self.torque_freq_hz, self.torque_tau, *self.wind_mean,
                *self.gust_std, self.gust_tau, self.gust_bound)
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("disturbance parameters must be finite")
        if min(*self.torque_amp, *self.gust_std, self.gust_bound) < 0:
            raise ValueError("disturbance amplitudes must be >= 0")
        if self.torque_tau <= 0 or self.gust_tau <= 0 or min(self.torque_freq_hz) < 0:
            raise ValueError("disturbance time constants must be > 0 and frequencies >= 0")

    @property
    def active(self) -> bool:
        return any(self.torque_amp) or any(self.gust_std) or any(self.wind_mean)

    @classmethod
    def moderate(cls) -> DisturbanceParams:
        """A breezy day: torques up to 0.03/0.03/0.01 N·m, 1 m/s gusts (0.3 vertical)."""
        return cls(torque_amp=(0.03, 0.03, 0.01), gust_std=(1.0, 1.0, 0.3), wind_mean=(1.0, 0.5, 0.0))


def ar1(a: float, w: np.ndarray, zi: float = 0.0) -> tuple[np.ndarray, float]:
    """The first-order recursion ``y[n] = a y[n-1] + w[n]`` with ``y[0] = w[0] + zi``; returns ``y`` and
    the state ``a y[-1]`` for the next block -- ``scipy.signal.lfilter([1], [1, -a], w, zi=[zi])``,
    without importing scipy.signal (75 MB in every edge process). A plain loop: one block
    of 2000 steps is 10 s of simulated flight."""
    y = np.empty(len(w))
    prev = zi
    for n, x in enumerate(w.tolist()):
        prev = x + prev
        y[n] = prev
        prev *= a
    return y, prev


class Disturbance:
    """Seeded, bounded disturbance sequence sampled once per physics step ``dt``, drawn ``block`` steps at a
    time (vectorised, filtered by :func:`ar1`)."""

    def __init__(self, params: DisturbanceParams, dt: float, rng: np.random.Generator, block: int = 2000):
        self.params = params
        self.dt = float(dt)
        self.rng = rng
        self.block = int(block)
        self._zero = (0.0, 0.0, 0.0, *map(float, params.wind_mean))
        self._active = params.active
        self._k = 0  # steps drawn so far
        self._buf: list[tuple[float, ...]] = []
        self._i = 0
        p = params
        self._freq = rng.uniform(p.torque_freq_hz[0], p.torque_freq_hz[1], 3) if self._active else np.zeros(3)
        self._phase = rng.uniform(0, 2 * math.pi, 3) if self._active else np.zeros(3)
        self._a_t = math.exp(-self.dt / p.torque_tau)
        self._a_g = math.exp(-self.dt / p.gust_tau)
        self._zi = np.zeros((6, 1))
        self._n0 = rng.normal(size=6) if self._active else np.zeros(6)

    def _refill(self) -> None:
        p, n = self.params, self.block
        w = self.rng.normal(size=(6, n))
        w[:3] *= math.sqrt(1 - self._a_t**2)
        w[3:] *= math.sqrt(1 - self._a_g**2)
        out = np.empty((6, n))
        for i in range(6):
            a = self._a_t if i < 3 else self._a_g
            if self._k == 0:  # start the OU processes in their stationary distribution
                self._zi[i, 0] = a * self._n0[i]
            out[i], self._zi[i, 0] = ar1(a, w[i], float(self._zi[i, 0]))
        t = (self._k + np.arange(n)) * self.dt
        amp = np.asarray(p.torque_amp)[:, None]
        sin = np.sin(2 * math.pi * self._freq[:, None] * t + self._phase[:, None])
        torque = amp * (0.6 * sin + 0.4 * np.clip(out[:3], -1, 1))
        gust = np.clip(out[3:] * np.asarray(p.gust_std)[:, None], -p.gust_bound, p.gust_bound)
        wind = gust + np.asarray(p.wind_mean)[:, None]
        self._buf = list(zip(*np.vstack([torque, wind]).tolist()))
        self._i = 0
        self._k += n

    def sample(self) -> tuple[float, ...]:
        """Next ``(d_φ, d_θ, d_ψ, w_x, w_y, w_z)``: torques in N·m, wind in m/s."""
        if not self._active:
            return self._zero
        if self._i >= len(self._buf):
            self._refill()
        s = self._buf[self._i]
        self._i += 1
        return s


def euler_rates_from_body_rates(att: tuple[float, float, float], rates: tuple[float, float, float]) -> tuple[float, float, float]:
    """Θ̇ = W(Θ)^-1 ω, the inverse of (P10). Singular at θ = ±90°."""
    phi, theta, _ = att
    p, q, r = rates
    sf, cf = math.sin(phi), math.cos(phi)
    ct = math.cos(theta)
    if abs(ct) < 1e-6:
        raise ValueError("Euler-rate kinematics are singular at pitch = ±90°")
    qs = q * sf + r * cf
    return (p + qs * math.sin(theta) / ct, q * cf - r * sf, qs / ct)


def body_rates_from_euler_rates(att: tuple[float, float, float], datt: tuple[float, float, float]) -> tuple[float, float, float]:
    """ω = W(Θ) Θ̇ (P10): ``[[1, 0, −sθ], [0, cφ, cθ sφ], [0, −sφ, cθ cφ]] Θ̇``."""
    phi, theta, _ = att
    dphi, dtheta, dpsi = datt
    sf, cf = math.sin(phi), math.cos(phi)
    st, ct = math.sin(theta), math.cos(theta)
    return (dphi - st * dpsi, cf * dtheta + ct * sf * dpsi, -sf * dtheta + ct * cf * dpsi)


def _deriv(s, T, ux, uy, uz, wx, wy, wz, c):
    """Right-hand side of the 12-state model; ``c`` holds the constants (see Quadrotor)."""
    _, _, _, vx, vy, vz, phi, theta, psi, p, q, r = s
    m_inv, kxy, kz, g, a1, a2, a3, ixx_inv, iyy_inv, izz_inv = c
    sf = math.sin(phi)
    cf = math.cos(phi)
    st = math.sin(theta)
    ct = math.cos(theta)
    sp = math.sin(psi)
    cp = math.cos(psi)
    tm = T * m_inv
    qs = q * sf + r * cf
    return (
        vx,
        vy,
        vz,
        tm * (cp * st * cf + sp * sf) - kxy * (vx - wx),
        tm * (sp * st * cf - cp * sf) - kxy * (vy - wy),
        tm * ct * cf - g - kz * (vz - wz),
        p + qs * st / ct,
        q * cf - r * sf,
        qs / ct,
        a1 * q * r + ux * ixx_inv,
        a2 * p * r + uy * iyy_inv,
        a3 * p * q + uz * izz_inv,
    )


class Quadrotor:
    """The plant: state, actuators, disturbance and RK4 integration at step ``dt`` (1/200 s or smaller),
    starting at rest and level at ``pos``, ``yaw``; ``ground_z`` None for no ground."""

    def __init__(self, params: QuadParams = QuadParams(), dt: float = 1 / 200,
                 disturbance: DisturbanceParams | None = None, rng: np.random.Generator | None = None,
                 pos: tuple[float, float, float] = (0.0, 0.0, 0.0), yaw: float = 0.0, ground_z: float | None = 0.0):
        if not (math.isfinite(dt) and 0 < dt <= 1 / 100):
            raise ValueError("dt must be in (0, 0.01] s (100 Hz or faster)")
        pos = tuple(float(v) for v in pos)
        if len(pos) != 3 or not all(math.isfinite(v) for v in pos) or not math.isfinite(yaw):
            raise ValueError("initial position must be 3 finite numbers and yaw finite")
        self.params = params
        self.dt = float(dt)
        P = params
        self._c = (
            1.0 / P.mass, P.drag_xy / P.mass, P.drag_z / P.mass, P.g,
            (P.iyy - P.izz), (P.izz - P.ixx), (P.ixx - P.iyy),  # f(X) of (P12), divided below
            1.0 / P.ixx, 1.0 / P.iyy, 1.0 / P.izz,
        )
        # fold 1/I into the gyroscopic coefficients: ω̇ = I^-1 (f + u + d)
        c = list(self._c)
        c[4] /= P.ixx
        c[5] /= P.iyy
        c[6] /= P.izz
        self._c = tuple(c)
        self._lag = math.exp(-self.dt / P.motor_tau) if P.motor_tau > 0 else 0.0
        self._tmax = P.thrust_max
        self._weight = P.mass * P.g
        self._umax = tuple(float(v) for v in P.torque_max)
        self.disturbance = Disturbance(disturbance or DisturbanceParams(), self.dt, rng or np.random.default_rng(0))
        self.ground_z = None if ground_z is None else float(ground_z)
        self.s: tuple[float, ...] = (*pos, 0.0, 0.0, 0.0, 0.0, 0.0, float(yaw), 0.0, 0.0, 0.0)
        #: applied (lagged, saturated) thrust and torques
        self.thrust = 0.0
        self.torque = (0.0, 0.0, 0.0)
        self.on_ground = self.ground_z is not None and pos[2] <= self.ground_z + 1e-9

    # ------------------------------------------------------------------ accessors
    @property
    def pos(self) -> tuple[float, float, float]:
        return self.s[0:3]

    @property
    def vel(self) -> tuple[float, float, float]:
        return self.s[3:6]

    @property
    def att(self) -> tuple[float, float, float]:
        return self.s[6:9]

    @property
    def rates(self) -> tuple[float, float, float]:
        return self.s[9:12]

    def rest_on_ground(self) -> None:
        """Put the vehicle at rest, level, on the ground below it (keeps x, y, yaw)."""
        s = self.s
        z = s[2] if self.ground_z is None else self.ground_z
        self.s = (s[0], s[1], z, 0.0, 0.0, 0.0, 0.0, 0.0, s[8], 0.0, 0.0, 0.0)
        self.thrust = 0.0
        self.torque = (0.0, 0.0, 0.0)
        self.on_ground = True

    # ------------------------------------------------------------------ integration
    def step(self, thrust: float, ux: float, uy: float, uz: float) -> None:
        """Advance one physics step with commanded thrust (N) and body torques (N·m).

        The commands go through the motor lag and the saturation, the disturbance is sampled,
        and the state is integrated by RK4; the ground (if any) stops downward motion.
        """
        lag = self._lag
        b = 1.0 - lag
        T = lag * self.thrust + b * thrust
        tx, ty, tz = self.torque
        tx = lag * tx + b * ux
        ty = lag * ty + b * uy
        tz = lag * tz + b * uz
        # saturation
        tmax = self._tmax
        T = 0.0 if T < 0.0 else (tmax if T > tmax else T)
        mx, my, mz = self._umax
        tx = -mx if tx < -mx else (mx if tx > mx else tx)
        ty = -my if ty < -my else (my if ty > my else ty)
        tz = -mz if tz < -mz else (mz if tz > mz else tz)
        if T != T or tx != tx or ty != ty or tz != tz:  # NaN guard
            raise ValueError("non-finite actuator command")
        self.thrust = T
        self.torque = (tx, ty, tz)
        d = self.disturbance.sample()
        gz = self.ground_z
        s = self.s
        if self.on_ground and T <= self._weight:
            # resting on the ground: the ground reaction holds the vehicle still
            return
        self.on_ground = False
        ux_, uy_, uz_ = tx + d[0], ty + d[1], tz + d[2]
        wx, wy, wz = d[3], d[4], d[5]
        c = self._c
        h = self.dt
        h2 = 0.5 * h
        k1 = _deriv(s, T, ux_, uy_, uz_, wx, wy, wz, c)
        k2 = _deriv(tuple(a + h2 * b for a, b in zip(s, k1)), T, ux_, uy_, uz_, wx, wy, wz, c)
        k3 = _deriv(tuple(a + h2 * b for a, b in zip(s, k2)), T, ux_, uy_, uz_, wx, wy, wz, c)
        k4 = _deriv(tuple(a + h * b for a, b in zip(s, k3)), T, ux_, uy_, uz_, wx, wy, wz, c)
        h6 = h / 6.0
        s = tuple(a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4))
        if gz is not None and s[2] < gz:
            # touched down: stop on the ground
            self.s = (s[0], s[1], gz, 0.0, 0.0, 0.0, s[6], s[7], s[8], s[9], s[10], s[11])
            if s[5] <= 0.0:
                self.rest_on_ground()
            return
        self.s = s
