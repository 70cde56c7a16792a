"""ArduCopter's start-up as a ground station sees it: boot, EKF origin, pre-arm, position estimate.

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/boot.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["BootTimeline", "EKF_FLAGS", "EKF_POS_HORIZ_ABS", "EKF_CONST_POS_MODE", "EKF_UNINITIALIZED",
           "EKF_HEALTHY", "position_ok", "ORIGIN_TEXT", "GPS_TEXT", "PREARM_WAITING_HOME"]

#: EKF_STATUS_FLAGS (common.xml)
EKF_FLAGS = {"ATTITUDE": 1, "VELOCITY_HORIZ": 2, "VELOCITY_VERT": 4, "POS_HORIZ_REL": 8, "POS_HORIZ_ABS": 16,
             "POS_VERT_ABS": 32, "POS_VERT_AGL": 64, "CONST_POS_MODE": 128, "PRED_POS_HORIZ_REL": 256,
             "PRED_POS_HORIZ_ABS": 512, "UNINITIALIZED": 1024}
EKF_POS_HORIZ_ABS = EKF_FLAGS["POS_HORIZ_ABS"]
EKF_CONST_POS_MODE = EKF_FLAGS["CONST_POS_MODE"]
EKF_UNINITIALIZED = EKF_FLAGS["UNINITIALIZED"]
#: what a healthy ArduCopter EKF reports with GPS (attitude, velocities, positions, predicted positions)
EKF_HEALTHY = 1 | 2 | 4 | 8 | 16 | 32 | 256 | 512
_EKF_NO_GPS = 1 | 4 | 32 | 128  # attitude, vertical velocity and position, constant-position mode
_EKF_ORIGIN = _EKF_NO_GPS | 2 | 8 | 256  # + horizontal velocity and relative position about the origin

ORIGIN_TEXT = "EKF3 IMU0 origin set"
GPS_TEXT = "EKF3 IMU0 is using GPS"
PREARM_WAITING_HOME = "AHRS: waiting for home"


def position_ok(flags: int) -> bool:
    """ArduCopter's ``position_ok()`` from EKF_STATUS_REPORT flags: absolute horizontal position, not in
    constant-position mode (AP_AHRS / Copter::ekf_has_absolute_position)."""
    return bool(flags & EKF_POS_HORIZ_ABS) and not flags & (EKF_CONST_POS_MODE | EKF_UNINITIALIZED)


@dataclass(frozen=True)
class BootTimeline:
    """ArduCopter's start-up times (s after power-on) times ``scale`` (see the module docstring)."""

    scale: float = 1.0
    boot_s: float = 2.0
    origin_s: float = 20.0
    armable_s: float = 24.0
    position_s: float = 42.0

    def __post_init__(self) -> None:
        if not (isinstance(self.scale, (int, float)) and math.isfinite(self.scale) and 0 <= self.scale <= 100):
            raise ValueError("boot scale must be in [0, 100] (1 = as ArduCopter's firmware, 0 = ready at once)")
        times = (self.boot_s, self.origin_s, self.armable_s, self.position_s)
        if not all(math.isfinite(x) and x >= 0 for x in times) or list(times) != sorted(times):
            raise ValueError("boot times must be finite, >= 0 and in order boot <= origin <= armable <= position")

    def _at(self, base: float) -> float:
        return base * self.scale

    def booting(self, t: float) -> bool:
        """MAV_STATE_BOOT (not initialised yet)."""
        return t < self._at(self.boot_s)

    def home_known(self, t: float) -> bool:
        """The EKF origin (and so home) is set."""
        return t >= self._at(self.origin_s)

    def armable(self, t: float) -> bool:
        """The pre-arm checks pass (for a mode that needs no position)."""
        return t >= self._at(self.armable_s)

    def position(self, t: float) -> bool:
        """The EKF uses GPS: absolute position, modes that need a position allowed."""
        return t >= self._at(self.position_s)

    def ekf_flags(self, t: float) -> int:
        """EKF_STATUS_REPORT flags at time t."""
        if self.booting(t):
            return EKF_UNINITIALIZED
        if self.position(t):
            return EKF_HEALTHY
        return _EKF_ORIGIN if self.home_known(t) else _EKF_NO_GPS

    def prearm_failure(self, t: float) -> str | None:
        """The first pre-arm check that fails at time t (None when armable)."""
        if self.armable(t):
            return None
        return PREARM_WAITING_HOME

    def texts_between(self, t0: float, t1: float) -> list[str]:
        """The start-up STATUSTEXTs whose time falls in (t0, t1] (``t0 < 0`` includes time 0)."""
        out = []
        for base, text in ((self.origin_s, ORIGIN_TEXT), (self.position_s, GPS_TEXT)):
            if t0 < self._at(base) <= t1:
                out.append(text)
        return out
