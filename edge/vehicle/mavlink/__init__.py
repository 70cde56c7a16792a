"""MAVLink vehicle driver: an autopilot behind :class:`~edge.vehicle.driver.VehicleDriver`, split by concern.

The edge's board talks to a real autopilot (or the sim autopilot, :mod:`edge.vehicle.mavsim`)
exactly as it talks to the built-in :class:`SimDriver`: this package maps the driver interface
onto MAVLink 2 (pymavlink, dialect ``ardupilotmega``). In the paper the Pixhawk does the
low-level control (PAPER.md Section 5: the built-in PID position loop) and the companion computer
the high-level control; this driver is the companion side: it streams the trajectory reference
of (P9) (plus the formation correction of (P8)) as position targets, or flies it as an AUTO
mission, and fires the capture points. As Skybrush's MAVLink extension, the concerns live apart:
:mod:`.link` (connection, signing, reader thread, our 1 Hz HEARTBEAT as a GCS, system 255 by default
so that ArduPilot's GCS failsafe watches this link), :mod:`.handlers` (a table from message type to
handler; frames), :mod:`.commands` (send a command and await the matching COMMAND_ACK;
:class:`CommandRefused` carries the MAV_RESULT), :mod:`.phase` (:class:`Phase`), :mod:`.dialect`
(the autopilot family behind an interface), :mod:`.params` (the parameter protocol), the flight
strategies :mod:`.guided` and :mod:`.auto` (one worker), and :mod:`.driver` binding them.

==================  ===============================================================
driver call         MAVLink
==================  ===============================================================
takeoff(alt)        DO_SET_MODE GUIDED, COMPONENT_ARM_DISARM(1), NAV_TAKEOFF(param7 = alt)
start(t0)           DO_SET_MODE GUIDED if not in it; then SET_POSITION_TARGET_LOCAL_NED stream
                    (flight "auto": mission upload first, AUTO from the start time)
hold()              DO_SET_MODE GUIDED if not in it; position target at the current position
resume()            as start, from the paused trajectory time
land()              NAV_LAND (ArduCopter switches to LAND and disarms on the ground)
return_to_launch()  NAV_RETURN_TO_LAUNCH (RTL mode)
capture             optionally DO_DIGICAM_CONTROL(param5 = 1 shoot, param6 = the capture id, apm.items)
==================  ===============================================================

Without a HEARTBEAT for ``heartbeat_timeout_s`` (3 s, the usual GCS "link lost" time) the state's
mode is FAILSAFE and every command raises :class:`VehicleLinkError` (a ValueError: the board turns
it into a rejected acknowledgement with the reason). ``step(until_t)`` receives the board's
mission clock; trajectory times, the transit to the first waypoint and the capture points run on
it, exactly as with the simulated vehicle (both drivers take the mission's reference from
:class:`edge.vehicle.sequencer.MissionSequencer`).
"""

from edge.vehicle.apm.modes import CopterMode

from .commands import CommandRefused, VehicleLinkError, command_name, result_name
from .dialect import ARDUCOPTER, Dialect, copter_mode, copter_mode_name
from .driver import MavlinkDriver, MavlinkParams
from .guided import TYPE_MASK_POS_VEL_ACC_YAW, TYPE_MASK_POS_VEL_YAW, TYPE_MASK_POS_YAW
from .handlers import attitude_ned_to_enu, enu_to_ned, ned_to_enu, rates_frd_to_flu, yaw_enu_to_ned, yaw_ned_to_enu
from .link import open_connection
from .phase import Phase
from .progress import MissionProgress

__all__ = [
    "CopterMode", "MavlinkParams", "MavlinkDriver", "VehicleLinkError", "CommandRefused", "Phase", "Dialect",
    "ARDUCOPTER", "TYPE_MASK_POS_VEL_YAW", "TYPE_MASK_POS_VEL_ACC_YAW", "TYPE_MASK_POS_YAW", "copter_mode",
    "copter_mode_name", "ned_to_enu", "enu_to_ned", "yaw_ned_to_enu", "yaw_enu_to_ned", "attitude_ned_to_enu",
    "rates_frd_to_flu", "open_connection", "result_name", "command_name", "MissionProgress",
]
