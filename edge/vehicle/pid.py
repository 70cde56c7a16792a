"""Position control: cascaded P-position / PID-velocity loop giving attitude and thrust references.

Design notes: docs/edge.md (edge/vehicle/pid.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from edge.vehicle.quadrotor import GRAVITY

__all__ = ["PIDGains", "PositionPID"]

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class PIDGains:
    """Gains and limits of the position controller (horizontal xy / vertical z): ``kp_*``, ``kv_*`` 1/s, ``ki_*``
    1/s², ``kd_*`` dimensionless, ``d_tau`` the derivative filter's time constant (s), ``i_max`` the integrator
    bound (m/s), speeds m/s, accelerations m/s², ``max_tilt`` rad."""

    kp_xy: float = 1.0
    kp_z: float = 1.5
    kv_xy: float = 2.5
    kv_z: float = 4.0
    ki_xy: float = 0.6
    ki_z: float = 2.0
    kd_xy: float = 0.05
    kd_z: float = 0.0
    d_tau: float = 0.05
    i_max: float = 1.5
    max_speed_xy: float = 10.0
    max_speed_up: float = 3.0
    max_speed_down: float = 2.0
    max_acc_xy: float = 5.0
    max_acc_up: float = 5.0
    max_acc_down: float = 4.0
    max_tilt: float = math.radians(35.0)

    def __post_init__(self) -> None:
        for k, v in self.__dict__.items():
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"PID parameter {k} must be finite and >= 0")
        if not 0 < self.max_tilt < math.pi / 2:
            raise ValueError("max_tilt must be in (0, 90°)")
        if self.d_tau <= 0:
            raise ValueError("d_tau must be > 0")


class PositionPID:
    """Cascaded position/velocity controller producing (roll_d, pitch_d, yaw_d) and thrust (at most
    ``thrust_max``), every ``dt``, from its own model of the ``mass`` and the linear ``drag`` (feed-forward)."""

    def __init__(self, mass: float, gains: PIDGains = PIDGains(), dt: float = 1 / 200,
                 drag: tuple[float, float] = (0.0, 0.0), thrust_max: float = math.inf, g: float = GRAVITY):
        if not (math.isfinite(mass) and mass > 0 and math.isfinite(dt) and dt > 0):
            raise ValueError("mass and dt must be finite and > 0")
        self.mass = float(mass)
        self.gains = gains
        self.dt = float(dt)
        self.drag = (float(drag[0]) / mass, float(drag[1]) / mass)
        self.thrust_max = float(thrust_max)
        self.g = float(g)
        self._d_a = math.exp(-self.dt / gains.d_tau)
        self.reset()

    def reset(self) -> None:
        """Zero the integrators and the derivative filter."""
        self.integral = [0.0, 0.0, 0.0]
        self._ev_prev: list[float] | None = None
        self._dev = [0.0, 0.0, 0.0]

    def update(self, pos: Vec3, vel: Vec3, att: Vec3, ref_pos: Vec3, ref_vel: Vec3 = (0.0, 0.0, 0.0),
               ref_acc: Vec3 = (0.0, 0.0, 0.0), ref_yaw: float = 0.0) -> tuple[float, float, float, float]:
        """One control period: ``(roll_d, pitch_d, yaw_d, thrust)`` in rad, rad, rad, N."""
        G = self.gains
        dt = self.dt
        # 1. position P -> velocity command, limited
        vcx = ref_vel[0] + G.kp_xy * (ref_pos[0] - pos[0])
        vcy = ref_vel[1] + G.kp_xy * (ref_pos[1] - pos[1])
        vcz = ref_vel[2] + G.kp_z * (ref_pos[2] - pos[2])
        h = math.hypot(vcx, vcy)
        if h > G.max_speed_xy:
            s = G.max_speed_xy / h
            vcx *= s
            vcy *= s
        vcz = max(-G.max_speed_down, min(G.max_speed_up, vcz))
        # 2. velocity PID -> acceleration command
        ev = (vcx - vel[0], vcy - vel[1], vcz - vel[2])
        prev = self._ev_prev if self._ev_prev is not None else ev
        a_d = self._d_a
        dev = self._dev
        for i in range(3):
            dev[i] = a_d * dev[i] + (1.0 - a_d) * (ev[i] - prev[i]) / dt
        self._ev_prev = ev
        I = self.integral
        kdx, kdz = self.drag
        ax = ref_acc[0] + G.kv_xy * ev[0] + G.ki_xy * I[0] + G.kd_xy * dev[0] + kdx * vel[0]
        ay = ref_acc[1] + G.kv_xy * ev[1] + G.ki_xy * I[1] + G.kd_xy * dev[1] + kdx * vel[1]
        az = ref_acc[2] + G.kv_z * ev[2] + G.ki_z * I[2] + G.kd_z * dev[2] + kdz * vel[2]
        sat = [False, False, False]
        h = math.hypot(ax, ay)
        # tilt limit: |a_h| <= (g + a_z) tan(max_tilt)
        az_c = max(-G.max_acc_down, min(G.max_acc_up, az))
        sat[2] = az_c != az
        az = az_c
        amax_h = min(G.max_acc_xy, max(0.0, (self.g + az)) * math.tan(G.max_tilt))
        if h > amax_h:
            s = amax_h / h
            ax *= s
            ay *= s
            sat[0] = sat[1] = True
        # conditional integration (anti-windup)
        i_max = G.i_max
        for i in range(3):
            if not (sat[i] and (ev[i] * I[i] >= 0.0)):
                v = I[i] + ev[i] * dt
                I[i] = -i_max if v < -i_max else (i_max if v > i_max else v)
        # 3. thrust vector -> attitude and thrust references
        m = self.mass
        fx, fy, fz = m * ax, m * ay, m * (az + self.g)
        phi, theta, psi = att
        cp, sp = math.cos(psi), math.sin(psi)
        fxb = fx * cp + fy * sp
        pitch_d = math.atan2(fxb, fz)
        roll_d = math.atan2(fx * sp - fy * cp, math.hypot(fxb, fz))
        sf, cf = math.sin(phi), math.cos(phi)
        st, ct = math.sin(theta), math.cos(theta)
        b3 = (cp * st * cf + sp * sf, sp * st * cf - cp * sf, ct * cf)
        thrust = fx * b3[0] + fy * b3[1] + fz * b3[2]
        thrust = 0.0 if thrust < 0.0 else min(thrust, self.thrust_max)
        return roll_d, pitch_d, ref_yaw, thrust
