"""GUIDED flight: the trajectory reference streamed as position targets.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/guided.py).
"""

from __future__ import annotations

import math
import time
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as M

from .handlers import yaw_enu_to_ned

__all__ = ["TargetStream", "Target", "TYPE_MASK_POS_VEL_YAW", "TYPE_MASK_POS_VEL_ACC_YAW", "TYPE_MASK_POS_YAW"]

Vec3 = tuple[float, float, float]
Target = tuple[Vec3, "Vec3 | None", "Vec3 | None", float]  # ENU position, velocity, acceleration, yaw

_IGNORE_ACC = (M.POSITION_TARGET_TYPEMASK_AX_IGNORE | M.POSITION_TARGET_TYPEMASK_AY_IGNORE
               | M.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
_IGNORE_VEL = (M.POSITION_TARGET_TYPEMASK_VX_IGNORE | M.POSITION_TARGET_TYPEMASK_VY_IGNORE
               | M.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
#: SET_POSITION_TARGET_LOCAL_NED type_mask: position, velocity feed-forward and yaw (2496)
TYPE_MASK_POS_VEL_YAW = _IGNORE_ACC | M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
#: SET_POSITION_TARGET_LOCAL_NED type_mask: position, velocity and acceleration feed-forward, yaw (2048)
TYPE_MASK_POS_VEL_ACC_YAW = M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
#: SET_POSITION_TARGET_LOCAL_NED type_mask: position and yaw only (2552)
TYPE_MASK_POS_YAW = TYPE_MASK_POS_VEL_YAW | _IGNORE_VEL


class TargetStream:
    """The position-target stream's pacing and encoding (``home``: the autopilot's NED origin in ENU)."""

    def __init__(self, rate_hz: float, home: Vec3):
        self.period, self.home = 1.0 / float(rate_hz), home
        self._next = -math.inf
        self._mono0 = time.monotonic()
        #: targets sent (count) and the last one (NED x, y, z, yaw), for inspection
        self.sent = 0
        self.last: tuple[float, float, float, float] | None = None
        #: the last message and when it went out (time.monotonic()), for a stream kept alive between steps
        self.last_msg: Any = None
        self.last_mono = -math.inf

    def restart(self) -> None:
        """Send the next target at once (a new phase)."""
        self._next = -math.inf

    def due(self, now: float) -> bool:
        """Whether a target goes out now: at most ``rate_hz`` on average; a tick up to 20 % of a period early
        still sends, so a caller ticking at exactly ``rate_hz`` is not halved by jitter."""
        if now < self._next - 0.2 * self.period:
            return False
        self._next = self._next + self.period if now - self._next < self.period else now + self.period
        return True

    def message(self, target: Target, sysid: int, compid: int) -> Any:
        """SET_POSITION_TARGET_LOCAL_NED for an ENU position (+ velocity, + acceleration) and yaw."""
        pos, vel, acc, yaw_enu = target
        h = self.home
        x, y, z = pos[1] - h[1], pos[0] - h[0], -(pos[2] - h[2])
        vx, vy, vz = (vel[1], vel[0], -vel[2]) if vel is not None else (0.0, 0.0, 0.0)
        ax, ay, az = (acc[1], acc[0], -acc[2]) if acc is not None else (0.0, 0.0, 0.0)
        if vel is None:
            mask = TYPE_MASK_POS_YAW
        else:
            mask = TYPE_MASK_POS_VEL_YAW if acc is None else TYPE_MASK_POS_VEL_ACC_YAW
        yaw = yaw_enu_to_ned(yaw_enu)
        ms = int((time.monotonic() - self._mono0) * 1000) & 0xFFFFFFFF
        self.sent += 1
        self.last = (x, y, z, yaw)
        self.last_mono = time.monotonic()
        self.last_msg = M.MAVLink_set_position_target_local_ned_message(ms, sysid, compid, M.MAV_FRAME_LOCAL_NED, mask,
                                                                        x, y, z, vx, vy, vz, ax, ay, az, yaw, 0)
        return self.last_msg
