"""Frame conversions between MAVLink's NED/FRD and the project's ENU/FLU.

MAVLink's local frame is NED (x north, y east, z down) about the EKF origin, and its body frame
FRD; ours is ENU about the mission origin with a FLU body. With the launch point ``home`` (ENU
m, where the autopilot's EKF origin is)::

    x_enu = y_ned + home_x,   y_enu = x_ned + home_y,   z_enu = −z_ned + home_z
    φ_enu = φ_ned,   θ_enu = −θ_ned,   ψ_enu = π/2 − ψ_ned  (wrapped to (−π, π])
    (p, q, r)_flu = (p, −q, −r)_frd

(the world change is the reflection that swaps x and y and flips z, the body change a half
turn about x; e.g. the ROS REP 103 / MAVROS ``ftf`` conversions). Each formula is its own inverse.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from edge.vehicle.angles import wrap_angle

__all__ = ["ned_to_enu", "enu_to_ned", "yaw_ned_to_enu", "yaw_enu_to_ned", "attitude_ned_to_enu",
           "rates_frd_to_flu"]

Vec3 = tuple[float, float, float]


def ned_to_enu(v: Any) -> np.ndarray:
    """NED vector(s) -> ENU: ``(x, y, z)_enu = (y, x, −z)_ned``; shape (..., 3), vectorised.

    Positions get the home offset added by the caller (the NED origin is the launch point).

    Examples
    --------
    >>> ned_to_enu([1.0, 2.0, -3.0]).tolist()
    [2.0, 1.0, 3.0]
    """
    a = np.asarray(v, dtype=float)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError("vector must have 3 components in its last axis")
    if not np.all(np.isfinite(a)):
        raise ValueError("vector must be finite")
    out = a[..., [1, 0, 2]].copy()
    out[..., 2] *= -1.0
    return out


def enu_to_ned(v: Any) -> np.ndarray:
    """ENU vector(s) -> NED (the same swap-and-flip as :func:`ned_to_enu`, its own inverse)."""
    return ned_to_enu(v)


def yaw_ned_to_enu(yaw: float) -> float:
    """Heading from north, clockwise (NED) -> from east, counter-clockwise (ENU): ``π/2 − ψ``, wrapped."""
    if not math.isfinite(yaw):
        raise ValueError("yaw must be finite")
    return wrap_angle(math.pi / 2.0 - yaw)


def yaw_enu_to_ned(yaw: float) -> float:
    """ENU yaw -> NED yaw (the same map: ``π/2 − ψ`` is an involution)."""
    return yaw_ned_to_enu(yaw)


def attitude_ned_to_enu(roll: float, pitch: float, yaw: float) -> Vec3:
    """ZYX Euler angles of an FRD body in NED -> of the FLU body in ENU: ``(φ, −θ, π/2 − ψ)``."""
    if not (math.isfinite(roll) and math.isfinite(pitch)):
        raise ValueError("roll and pitch must be finite")
    return (float(roll), -float(pitch), yaw_ned_to_enu(yaw))


def rates_frd_to_flu(p: float, q: float, r: float) -> Vec3:
    """Body rates about FRD axes -> about FLU axes: ``(p, −q, −r)`` (also the inverse)."""
    return (float(p), -float(q), -float(r))
