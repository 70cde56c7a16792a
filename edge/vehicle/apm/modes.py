"""ArduCopter's mode rules the sim autopilot applies (ardupilot.org/copter/docs/flight-modes.html).

Custom modes (HEARTBEAT.custom_mode): 0 STABILIZE, 3 AUTO, 4 GUIDED, 5 LOITER, 6 RTL, 9 LAND,
17 BRAKE. :func:`check_mode_change` says whether a change is allowed and why not, as the
STATUSTEXT ArduCopter sends ("Mode change to AUTO failed: ..."):

- STABILIZE in flight is refused here (the simulation has no pilot sticks to fly it);
- RTL needs the vehicle armed and flying (ArduCopter: RTL from the ground is refused);
- AUTO needs a mission with at least one item after home; from the ground, armed, its first
  NAV item must be a NAV_TAKEOFF ("Missing Takeoff Cmd"). Armed on the ground in AUTO, the
  mission starts at once, as ArduCopter with AUTO_OPTIONS bit 2 ("allow takeoff without
  raising throttle"; this simulation has no throttle stick).
- Arming is allowed in STABILIZE, GUIDED and LOITER (ArduCopter refuses arming in AUTO, RTL,
  LAND and BRAKE unless AUTO_OPTIONS bit 0 allows AUTO).
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["CopterMode", "SUPPORTED_MODES", "ARMABLE", "check_mode_change", "FS_GCS_ACTIONS", "FENCE_ACTIONS"]


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

#: FS_GCS_ENABLE value -> the mode the GCS failsafe switches to (2: AUTO continues, else RTL)
FS_GCS_ACTIONS = {1: CopterMode.RTL, 2: CopterMode.RTL, 3: CopterMode.RTL, 4: CopterMode.LAND,
                  5: CopterMode.LAND, 6: CopterMode.RTL, 7: CopterMode.BRAKE}
#: FENCE_ACTION value -> mode (0 = report only): 1 RTL or land, 2 land, 3 SmartRTL or RTL, 4 brake, 5 SmartRTL or land
FENCE_ACTIONS = {1: CopterMode.RTL, 2: CopterMode.LAND, 3: CopterMode.RTL, 4: CopterMode.BRAKE, 5: CopterMode.RTL}


def check_mode_change(mode: float, *, airborne: bool, armed: bool, mission_items: int,
                      first_nav: int | None) -> tuple[CopterMode | None, str]:
    """``(mode, "")`` when the change to ``mode`` is allowed, else ``(None, reason)``.

    ``mission_items`` counts the stored mission's items after home; ``first_nav`` is the command
    of its first NAV item (None without one).
    """
    try:
        m = CopterMode(int(mode))
    except (ValueError, OverflowError):
        return None, "unknown mode"
    if mode != int(mode) or m not in SUPPORTED_MODES:
        return None, "not supported"
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
