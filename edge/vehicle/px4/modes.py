"""PX4's flight modes as MAVLink carries them (PX4 ``src/modules/commander/px4_custom_mode.h``).

Design notes: docs/hardware-mavlink.md (edge/vehicle/px4/modes.py).
"""

from __future__ import annotations

import math
from enum import IntEnum

from protocol.messages import Mode

__all__ = ["Main", "AutoSub", "custom_mode", "split", "mode_name", "board_mode", "OFFBOARD", "MISSION", "LOITER",
           "RTL", "LAND", "TAKEOFF", "POSCTL", "ALTCTL", "RC_MODES", "base_mode", "check_mode_change",
           "set_mode_params", "from_set_mode"]


class Main(IntEnum):
    """PX4_CUSTOM_MAIN_MODE."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoSub(IntEnum):
    """PX4_CUSTOM_SUB_MODE_AUTO."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8
    PRECLAND = 9


def custom_mode(main: int, sub: int = 0) -> int:
    """HEARTBEAT.custom_mode of a main and sub mode: ``(sub << 24) | (main << 16)``."""
    return ((int(sub) & 0xFF) << 24) | ((int(main) & 0xFF) << 16)


def split(custom: int) -> tuple[int, int]:
    """``(main, sub)`` of a custom mode (the low 16 bits are unused by PX4)."""
    c = int(custom) & 0xFFFFFFFF
    return (c >> 16) & 0xFF, (c >> 24) & 0xFF


OFFBOARD = custom_mode(Main.OFFBOARD)
MISSION = custom_mode(Main.AUTO, AutoSub.MISSION)
LOITER = custom_mode(Main.AUTO, AutoSub.LOITER)
RTL = custom_mode(Main.AUTO, AutoSub.RTL)
LAND = custom_mode(Main.AUTO, AutoSub.LAND)
TAKEOFF = custom_mode(Main.AUTO, AutoSub.TAKEOFF)
POSCTL = custom_mode(Main.POSCTL)
ALTCTL = custom_mode(Main.ALTCTL)
#: main modes flown by the pilot's sticks (need an RC transmitter)
RC_MODES = frozenset({Main.MANUAL, Main.ALTCTL, Main.POSCTL, Main.ACRO, Main.STABILIZED})

_TO_BOARD = {MISSION: Mode.MISSION, OFFBOARD: Mode.HOLD, LOITER: Mode.HOLD, RTL: Mode.RTL, LAND: Mode.LAND,
             custom_mode(Main.AUTO, AutoSub.PRECLAND): Mode.LAND, TAKEOFF: Mode.TAKEOFF}


def _known(custom: int) -> bool:
    main, sub = split(custom)
    if int(custom) & 0xFFFF or main not in Main._value2member_map_:
        return False
    if main == Main.AUTO:
        return sub in AutoSub._value2member_map_
    return sub == 0


def mode_name(custom: int) -> str:
    """PX4's name of a custom mode as QGroundControl shows it ("OFFBOARD", "AUTO.MISSION"; ``MODE_0x...`` when
    unknown)."""
    try:
        c = int(custom)
    except (TypeError, ValueError, OverflowError):
        return "MODE_?"
    if not _known(c):
        return f"MODE_0x{c & 0xFFFFFFFF:08X}"
    main, sub = split(c)
    return f"AUTO.{AutoSub(sub).name}" if main == Main.AUTO else Main(main).name


def board_mode(custom: int) -> Mode:
    """The board's mode for a PX4 custom mode flown by someone else (pilot, failsafe): see the module docstring."""
    return _TO_BOARD.get(int(custom), Mode.PILOT)


def set_mode_params(custom: int) -> tuple[float, ...]:
    """MAV_CMD_DO_SET_MODE's param1..3 for a PX4 custom mode."""
    main, sub = split(custom)
    return (1.0, float(main), float(sub))


def from_set_mode(param2: float, param3: float) -> int | None:
    """The custom mode DO_SET_MODE's param2 (main) and param3 (sub) ask for; None when not integers in range."""
    if not (math.isfinite(param2) and math.isfinite(param3)):
        return None
    if param2 != int(param2) or param3 != int(param3) or not (0 <= param2 <= 255 and 0 <= param3 <= 255):
        return None
    return custom_mode(int(param2), int(param3))


#: MAV_MODE_FLAG bits (common.xml)
_CUSTOM, _AUTO, _GUIDED, _STABILIZE, _MANUAL, _ARMED = 1, 4, 8, 16, 64, 128


def base_mode(custom: int, *, armed: bool) -> int:
    """HEARTBEAT.base_mode as PX4's mavlink module computes it (``get_mavlink_mode_state``): CUSTOM_MODE_ENABLED
    always; AUTO, GUIDED and STABILIZE in the AUTO modes and OFFBOARD; MANUAL_INPUT (+ STABILIZE, + GUIDED in
    POSCTL) in the RC modes; SAFETY_ARMED when armed."""
    main, _ = split(custom)
    flags = _CUSTOM | (_ARMED if armed else 0)
    if main in (Main.AUTO, Main.OFFBOARD):
        flags |= _AUTO | _GUIDED | _STABILIZE
    elif main == Main.POSCTL:
        flags |= _MANUAL | _STABILIZE | _GUIDED
    elif main in (Main.ALTCTL, Main.STABILIZED):
        flags |= _MANUAL | _STABILIZE
    elif main in (Main.MANUAL, Main.ACRO):
        flags |= _MANUAL
    return flags


def check_mode_change(custom: int, *, rc: bool, offboard_signal: bool, mission_items: int, home: bool,
                      armed: bool, airborne: bool) -> tuple[bool, str]:
    """``(True, "")`` when PX4 would switch to ``custom`` now, else ``(False, reason)`` (a STATUSTEXT shorter than
    PX4's "Switching to Offboard is currently not available", which arrives in chunks)."""
    if not _known(custom):
        return False, "unknown mode"
    main, sub = split(custom)
    name = mode_name(custom)
    if main in RC_MODES and not rc:
        return False, f"{name} not available: no RC"
    if main == Main.OFFBOARD and not offboard_signal:
        return False, "Offboard not available: no setpoints"
    if main == Main.AUTO:
        if sub in (AutoSub.FOLLOW_TARGET, AutoSub.PRECLAND, AutoSub.READY):
            return False, f"{name} not available"
        if not home:
            return False, f"{name} not available: no home position"
        if sub == AutoSub.MISSION and mission_items < 1:
            return False, "Mission not available: no valid mission"
        if sub == AutoSub.RTL and not (armed and airborne):
            return False, "Return not available: landed"
    return True, ""
