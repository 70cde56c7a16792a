"""The autopilot family behind the driver, as a small interface.

:class:`Dialect` is what the driver asks of an autopilot family; :data:`ARDUCOPTER` answers for
ArduCopter (custom modes :class:`.apm.modes.CopterMode`, the 4.6 and 4.7 parameter naming schemes
of :mod:`.apm.params`, EKF readiness as :func:`.apm.boot.position_ok`). A PX4 dialect (custom
mode ``(sub_mode << 24) | (main_mode << 16)``, OFFBOARD as its guided mode, one parameter scheme)
would be another implementation. A mode the driver did not command reads, for ArduCopter
(:func:`copter_mode`): AUTO -> MISSION; GUIDED, BRAKE -> HOLD; RTL, SMART_RTL -> RTL; LAND -> LAND;
any other (pilot-flown: LOITER, STABILIZE, ALT_HOLD, POSHOLD, ... which follow the RC sticks, so
without RC input LOITER descends) -> PILOT, never HOLD; the state's ``autopilot.mode`` names it.
"""

from __future__ import annotations

from typing import Protocol

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.apm import params as P
from edge.vehicle.apm.boot import position_ok
from edge.vehicle.apm.modes import CopterMode
from protocol.messages import Mode

from .phase import Phase

__all__ = ["Dialect", "ArduCopter", "ARDUCOPTER", "copter_mode", "copter_mode_name"]


class Dialect(Protocol):
    """What the driver needs to know of an autopilot family."""

    name: str
    autopilot: int  # the HEARTBEAT's MAV_AUTOPILOT of this family
    guided: int  # the custom mode that follows the companion's position targets
    auto: int  # the custom mode that flies the uploaded mission
    schemes: tuple[str, ...]  # parameter naming schemes, oldest first

    def phase_mode(self, phase: Phase) -> int | None: ...  # the custom mode of a driver phase (None: any)
    def board_mode(self, custom_mode: int) -> Mode: ...  # a mode someone else chose, as the board's
    def mode_name(self, custom_mode: int) -> str: ...
    def set_mode_params(self, custom_mode: int) -> tuple[float, ...]: ...  # MAV_CMD_DO_SET_MODE's params
    def position_ok(self, ekf_flags: int) -> bool: ...  # EKF_STATUS_REPORT flags allow the position modes
    def param_name(self, key: str, scheme: str) -> str: ...
    def param_type(self, key: str, scheme: str) -> int: ...
    def to_raw(self, key: str, si: float, scheme: str) -> float: ...
    def from_raw(self, key: str, raw: float, scheme: str) -> float: ...


_COPTER_TO_MODE = {CopterMode.AUTO: Mode.MISSION, CopterMode.GUIDED: Mode.HOLD,
                   CopterMode.BRAKE: Mode.HOLD, CopterMode.RTL: Mode.RTL, CopterMode.SMART_RTL: Mode.RTL,
                   CopterMode.LAND: Mode.LAND}
_PHASE_COPTER = {Phase.TAKEOFF: CopterMode.GUIDED, Phase.HOLD: CopterMode.GUIDED, Phase.MISSION: CopterMode.GUIDED,
                 Phase.LAND: CopterMode.LAND, Phase.RTL: CopterMode.RTL, Phase.AUTO: CopterMode.AUTO}


def copter_mode(custom_mode: int) -> Mode:
    """The board's mode for an ArduCopter custom mode flown by someone else (pilot, failsafe)."""
    return _COPTER_TO_MODE.get(custom_mode, Mode.PILOT)


def copter_mode_name(custom_mode: int) -> str:
    """ArduCopter's name of a custom mode (``MODE_<n>`` when unknown)."""
    return mavutil.mode_mapping_acm.get(int(custom_mode), f"MODE_{int(custom_mode)}")


class ArduCopter:
    """ArduCopter's dialect (see the module docstring)."""

    name, autopilot, schemes = "ArduCopter", M.MAV_AUTOPILOT_ARDUPILOTMEGA, P.SCHEMES
    guided, auto = CopterMode.GUIDED, CopterMode.AUTO
    board_mode, mode_name = staticmethod(copter_mode), staticmethod(copter_mode_name)
    position_ok = staticmethod(position_ok)
    param_name, param_type = staticmethod(P.param_name), staticmethod(P.param_type)
    to_raw, from_raw = staticmethod(P.to_raw), staticmethod(P.from_raw)

    def phase_mode(self, phase: Phase) -> int | None:
        return _PHASE_COPTER.get(phase)

    def set_mode_params(self, custom_mode: int) -> tuple[float, ...]:
        return (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, int(custom_mode))


ARDUCOPTER: Dialect = ArduCopter()
