"""Mission-item conventions shared by the exporters (.plan, WPL), the driver and the sim autopilot.

Design notes: docs/hardware-mavlink.md (edge/geometry/ardupilot_items.py).
"""

from __future__ import annotations

import math

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_CHANGE_SPEED = 178
MAV_CMD_DO_SET_CAM_TRIGG_DIST = 206
MAV_CMD_DO_DIGICAM_CONTROL = 203
MAV_CMD_NAV_FENCE_RETURN_POINT = 5000
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION = 5003
MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION = 5004
MAV_CMD_NAV_RALLY_POINT = 5100

MAV_FRAME_GLOBAL = 0
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3

#: DO_CHANGE_SPEED param1 speed type: 1 = ground speed (common.xml SPEED_TYPE_GROUNDSPEED)
SPEED_TYPE_GROUNDSPEED = 1
#: the largest capture id a float32 parameter carries exactly
MAX_CAPTURE_ID = 2**24


def capture_params(capture_id: int) -> tuple[float, float, float, float, float, float, float]:
    """param1..param7 of the DO_DIGICAM_CONTROL item (or command) that takes capture ``capture_id``."""
    if not (isinstance(capture_id, int) and 0 <= capture_id <= MAX_CAPTURE_ID):
        raise ValueError(f"capture id must be an int in 0..{MAX_CAPTURE_ID}, got {capture_id!r}")
    return (0.0, 0.0, 0.0, 0.0, 1.0, float(capture_id), 0.0)


def capture_id(params: tuple[float, ...]) -> int | None:
    """The capture id of a DO_DIGICAM_CONTROL's params (param5 = 1 shoot), or None when it does not shoot."""
    if len(params) < 6 or params[4] != 1.0:
        return None
    v = params[5]
    if not (math.isfinite(v) and v == int(v) and 0 <= v <= MAX_CAPTURE_ID):
        return None
    return int(v)


def speed_params(speed: float) -> tuple[float, float, float, float, float, float, float]:
    """param1..param7 of DO_CHANGE_SPEED to ground speed ``speed`` m/s (throttle −1: no change)."""
    if not (math.isfinite(speed) and 0 < speed <= 100):
        raise ValueError(f"speed must be in (0, 100] m/s, got {speed!r}")
    return (float(SPEED_TYPE_GROUNDSPEED), float(speed), -1.0, 0.0, 0.0, 0.0, 0.0)
