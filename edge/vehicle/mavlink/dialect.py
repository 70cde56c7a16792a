"""The autopilot family behind the driver, as a small interface.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/dialect.py).
"""

from __future__ import annotations

from typing import Protocol

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.apm import params as P
from edge.vehicle.apm.boot import position_ok
from edge.vehicle.apm.modes import CopterMode
from edge.vehicle.px4 import modes as PXM
from edge.vehicle.px4 import params as PXP
from protocol.messages import Mode

from .phase import Phase

__all__ = ["Dialect", "ArduCopter", "ARDUCOPTER", "Px4", "PX4", "DIALECTS", "dialect_for", "copter_mode",
           "copter_mode_name"]


class Dialect(Protocol):
    """What the driver needs to know of an autopilot family."""

    name: str
    autopilot: int  # the HEARTBEAT's MAV_AUTOPILOT of this family
    guided: int  # the custom mode that follows the companion's position targets
    auto: int  # the custom mode that flies the uploaded mission
    schemes: tuple[str, ...]  # parameter naming schemes, oldest first
    arm_mode: int  # the mode the driver arms in before a takeoff
    setpoint_stream: bool  # the guided mode needs a position setpoint stream before and while in it (OFFBOARD)
    confirm_mode: bool  # a DO_SET_MODE's ACCEPTED is confirmed by a HEARTBEAT in the mode (or refused later)
    home_item: bool  # mission item 0 is home (ArduPilot) rather than the first real item (PX4)
    param_bitcast: bool  # integer parameters travel byte-wise in PARAM_VALUE's float (PX4)
    preflight_params: tuple[tuple[str, float], ...]  # (key, SI value) the driver sets before the first takeoff

    def phase_modes(self, phase: Phase) -> frozenset[int]: ...  # the custom modes a phase may show
    def takeoff_altitude(self, altitude: float, home_amsl: float | None) -> float: ...  # NAV_TAKEOFF param7
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

    arm_mode = CopterMode.GUIDED
    setpoint_stream = confirm_mode = param_bitcast = False
    home_item = True
    preflight_params: tuple[tuple[str, float], ...] = ()

    def phase_mode(self, phase: Phase) -> int | None:
        return _PHASE_COPTER.get(phase)

    def phase_modes(self, phase: Phase) -> frozenset[int]:
        m = _PHASE_COPTER.get(phase)
        return frozenset() if m is None else frozenset({int(m)})

    def takeoff_altitude(self, altitude: float, home_amsl: float | None) -> float:
        """ArduCopter's NAV_TAKEOFF takes the altitude above home."""
        return float(altitude)

    def set_mode_params(self, custom_mode: int) -> tuple[float, ...]:
        return (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, int(custom_mode))


ARDUCOPTER: Dialect = ArduCopter()

_PHASE_PX4 = {Phase.TAKEOFF: frozenset({PXM.TAKEOFF, PXM.LOITER}),
              Phase.HOLD: frozenset({PXM.OFFBOARD, PXM.LOITER, PXM.TAKEOFF}),  # the climb settles in TAKEOFF
              Phase.MISSION: frozenset({PXM.OFFBOARD}), Phase.LAND: frozenset({PXM.LAND}),
              Phase.RTL: frozenset({PXM.RTL, PXM.LAND}), Phase.AUTO: frozenset({PXM.MISSION, PXM.LOITER})}


class Px4:
    """PX4's dialect (see the module docstring): OFFBOARD is the guided mode (a setpoint stream at >= 2 Hz
    started before the switch and kept while in it, docs.px4.io "Offboard Mode"); the takeoff is AUTO.TAKEOFF
    (NAV_TAKEOFF param7 above mean sea level), after which PX4 holds in AUTO.LOITER; AUTO.MISSION flies the
    mission (whose end holds in AUTO.LOITER); a data-link loss returns home (NAV_DLL_ACT = 2, off by default)."""

    name, autopilot, schemes = "PX4", M.MAV_AUTOPILOT_PX4, PXP.SCHEMES
    guided, auto, arm_mode = PXM.OFFBOARD, PXM.MISSION, PXM.LOITER
    setpoint_stream = confirm_mode = param_bitcast = True
    home_item = False
    preflight_params = (("link_loss_action", float(PXP.NAV_DLL_ACT_RETURN)),)
    board_mode, mode_name = staticmethod(PXM.board_mode), staticmethod(PXM.mode_name)
    param_name, param_type = staticmethod(PXP.param_name), staticmethod(PXP.param_type)
    to_raw, from_raw = staticmethod(PXP.to_raw), staticmethod(PXP.from_raw)

    def phase_mode(self, phase: Phase) -> int | None:
        return {Phase.TAKEOFF: PXM.TAKEOFF, Phase.HOLD: PXM.OFFBOARD, Phase.MISSION: PXM.OFFBOARD,
                Phase.LAND: PXM.LAND, Phase.RTL: PXM.RTL, Phase.AUTO: PXM.MISSION}.get(phase)

    def phase_modes(self, phase: Phase) -> frozenset[int]:
        return _PHASE_PX4.get(phase, frozenset())

    def position_ok(self, ekf_flags: int) -> bool:
        """PX4 sends no EKF_STATUS_REPORT; were one relayed, the same absolute-position bit decides."""
        return position_ok(ekf_flags)

    def takeoff_altitude(self, altitude: float, home_amsl: float | None) -> float:
        """PX4's NAV_TAKEOFF param7 is above mean sea level: home's altitude plus ``altitude``."""
        if home_amsl is None:
            raise ValueError("take off: the autopilot's home position is not known yet")
        return float(home_amsl) + float(altitude)

    def set_mode_params(self, custom_mode: int) -> tuple[float, ...]:
        return PXM.set_mode_params(custom_mode)


PX4: Dialect = Px4()
#: MAV_AUTOPILOT -> its dialect
DIALECTS: dict[int, Dialect] = {M.MAV_AUTOPILOT_ARDUPILOTMEGA: ARDUCOPTER, M.MAV_AUTOPILOT_PX4: PX4}


def dialect_for(autopilot: int | None) -> Dialect | None:
    """The dialect of a HEARTBEAT's ``autopilot`` field (None: a family the driver does not speak)."""
    return DIALECTS.get(autopilot) if autopilot is not None else None
