"""ArduCopter's mode rules the sim autopilot applies (ardupilot.org/copter/docs/flight-modes.html).

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/modes.py).
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["CopterMode", "SUPPORTED_MODES", "ARMABLE", "REQUIRES_POSITION", "base_mode", "check_mode_change", "FS_GCS_ACTIONS", "FENCE_ACTIONS"]


class CopterMode(IntEnum):
    """ArduCopter custom modes (HEARTBEAT.custom_mode)."""

    STABILIZE = 0
    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    LAND = 9
    POSHOLD = 16
    BRAKE = 17
    SMART_RTL = 21


SUPPORTED_MODES = frozenset({CopterMode.STABILIZE, CopterMode.AUTO, CopterMode.GUIDED, CopterMode.LOITER,
                             CopterMode.RTL, CopterMode.LAND, CopterMode.BRAKE})
ARMABLE = frozenset({CopterMode.STABILIZE, CopterMode.GUIDED, CopterMode.LOITER})
#: modes whose ``requires_position()`` is true in ArduCopter (mode.h)
REQUIRES_POSITION = frozenset({CopterMode.AUTO, CopterMode.GUIDED, CopterMode.LOITER, CopterMode.RTL,
                               CopterMode.BRAKE, CopterMode.POSHOLD, CopterMode.SMART_RTL})
#: modes that run the horizontal position controller (MAV_MODE_FLAG_GUIDED_ENABLED while it is active)
_POSITION_CONTROL = REQUIRES_POSITION | {CopterMode.LAND}

#: MAV_MODE_FLAG bits (common.xml)
_CUSTOM, _GUIDED, _STABILIZE, _MANUAL, _ARMED = 1, 8, 16, 64, 128


def base_mode(mode: int, *, armed: bool, flying: bool) -> int:
    """HEARTBEAT.base_mode as ArduCopter computes it (GCS_MAVLINK_Copter::base_mode): STABILIZE_ENABLED,
    MANUAL_INPUT_ENABLED and CUSTOM_MODE_ENABLED always; GUIDED_ENABLED while the horizontal position
    controller runs (a position mode, armed and flying); SAFETY_ARMED when armed. So 81 disarmed (any
    mode), 209 armed on the ground or in STABILIZE, 217 flying in GUIDED or AUTO."""
    flags = _STABILIZE | _MANUAL | _CUSTOM | (_ARMED if armed else 0)
    if armed and flying and mode in _POSITION_CONTROL:
        flags |= _GUIDED
    return flags

#: modes flown by the pilot's sticks (throttle = climb rate; horizontal position held with centred sticks)
STICK_MODES = frozenset({CopterMode.LOITER, CopterMode.ALT_HOLD, CopterMode.POSHOLD})
#: descent with the throttle stick at its bottom, m/s: ArduCopter's PILOT_SPEED_DN, whose default 0 means
#: PILOT_SPEED_UP (250 cm/s) (Copter::get_pilot_speed_dn); with no RC input the throttle rests there
PILOT_DESCENT_MS = 2.5

#: FS_GCS_ENABLE value -> the mode the GCS failsafe switches to (2: AUTO continues, else RTL)
FS_GCS_ACTIONS = {1: CopterMode.RTL, 2: CopterMode.RTL, 3: CopterMode.RTL, 4: CopterMode.LAND,
                  5: CopterMode.LAND, 6: CopterMode.RTL, 7: CopterMode.BRAKE}
#: FENCE_ACTION value -> mode (0 = report only): 1 RTL or land, 2 land, 3 SmartRTL or RTL, 4 brake, 5 SmartRTL or land
FENCE_ACTIONS = {1: CopterMode.RTL, 2: CopterMode.LAND, 3: CopterMode.RTL, 4: CopterMode.BRAKE, 5: CopterMode.RTL}


def check_mode_change(mode: float, *, airborne: bool, armed: bool, mission_items: int,
                      first_nav: int | None, position_ok: bool = True) -> tuple[CopterMode | None, str]:
    """``(mode, "")`` when the change to ``mode`` is allowed, else ``(None, reason)``.

    ``mission_items`` counts the stored mission's items after home; ``first_nav`` is the command
    of its first NAV item (None without one); ``position_ok`` says the EKF has an absolute position.
    """
    try:
        m = CopterMode(int(mode))
    except (ValueError, OverflowError):
        return None, "unknown mode"
    if mode != int(mode) or m not in SUPPORTED_MODES:
        return None, "not supported"
    if m in REQUIRES_POSITION and not position_ok:
        return None, "requires position"
    if m == CopterMode.STABILIZE and airborne:
        return None, "not simulated in flight"
    if m == CopterMode.RTL and not (armed and airborne):
        return None, "requires armed and flying"
    if m == CopterMode.AUTO:
        if mission_items < 1:
            return None, "no mission"
        if armed and not airborne and first_nav != 22:
            return None, "Missing Takeoff Cmd"
    return m, ""
