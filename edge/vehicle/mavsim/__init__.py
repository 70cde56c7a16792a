"""The sim autopilot: a MAVLink 2 vehicle that behaves like ArduCopter, flown by the project's simulation.

ArduPilot SITL cannot be fetched here, so :class:`MavlinkSimVehicle` stands in for ArduCopter 4.5
towards real ground stations (QGroundControl, Mission Planner, MAVProxy, MAVSDK) and towards
:class:`edge.vehicle.mavlink.MavlinkDriver`, with :class:`edge.vehicle.sim.SimDriver` (6-DoF plant
(P10)-(P12), PID position loop, ATSM attitude loop (P13)-(P17)) flying underneath. The rules live in
pure modules (:mod:`edge.vehicle.apm`: modes, params, streams, missions, auto, signing); this module
is the socket shell, split as the driver is: :mod:`.vehicle` (the link, the table from message
type to handler, the vehicle model glue: AUTO, failsafes, fence), :mod:`.commands` (COMMAND_LONG /
COMMAND_INT as a table from MAV_CMD to handler, modes, arming, GUIDED targets), :mod:`.telemetry`
(what it sends) and :mod:`.cli` (one command line). It runs in a thread (tests), or as
``skynet sim-autopilot`` = ``python -m edge.vehicle.mavsim`` (one or several instances with
distinct ``--uav`` = system ids)::

    skynet sim-autopilot --uav 1 --connection udpout:127.0.0.1:14550 --speed 1

Message by message (system id = ``uav``, component 1, MAV_TYPE_QUADROTOR, MAV_AUTOPILOT_ARDUPILOTMEGA):

- **HEARTBEAT** 1 Hz: ArduCopter custom mode (:mod:`.apm.modes`), base_mode as ArduCopter's
  (:func:`.apm.modes.base_mode`: 81 disarmed, 217 flying in GUIDED or AUTO), system status BOOT
  while booting, STANDBY on the ground (armed or not), ACTIVE only airborne, CRITICAL in a failsafe.
- **Start-up** (:mod:`.apm.boot`, ``boot_scale``; 1 = ArduCopter's own times, the CLI's default):
  BOOT ~2 s; home (HOME_POSITION, LOCAL_POSITION_NED) after "EKF3 IMU0 origin set" ~20 s; arming
  refused with "PreArm:"/"Arm:" STATUSTEXT until ~24 s; GUIDED/AUTO/LOITER/RTL/BRAKE refused ("Mode
  change to GUIDED failed: requires position") until "EKF3 IMU0 is using GPS" ~42 s;
  EKF_STATUS_REPORT flags follow.
- **Telemetry** only when asked, as ArduCopter's firmware: HEARTBEAT alone until a request
  (SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM, REQUEST_MESSAGE); ``stream_all`` (``--stream-all``)
  streams the set below unasked at the rates of :mod:`.apm.streams` (wall clock): SYS_STATUS (gyro, accel, mag,
  GPS, AHRS, geofence, pre-arm sensors present/enabled/healthy, as ArduCopter sets them; geofence
  enabled with FENCE_ENABLE, unhealthy while breached; pre-arm healthy unless ``refuse_arming``),
  GPS_RAW_INT (3D fix, 12 satellites), GLOBAL_POSITION_INT, LOCAL_POSITION_NED (NED about home),
  ATTITUDE (FRD), VFR_HUD, BATTERY_STATUS, EXTENDED_SYS_STATE (landed state), HOME_POSITION,
  MISSION_CURRENT, EKF_STATUS_REPORT. Geodetic positions: the ENU frame's ``origin`` (lat, lon, alt) with pymap3d.
- **Requests**: SET_MESSAGE_INTERVAL / GET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM, REQUEST_MESSAGE
  (any streamed message, AUTOPILOT_VERSION, and the rest DENIED), REQUEST_AUTOPILOT_CAPABILITIES,
  GET_HOME_POSITION. AUTOPILOT_VERSION: ArduCopter 4.5.7 official, MISSION_INT | COMMAND_INT |
  PARAM_FLOAT | SET_POSITION_TARGET_LOCAL_NED | MISSION_FENCE | MISSION_RALLY | MAVLINK2 (no FTP).
- **COMMAND_LONG and COMMAND_INT**: every one addressed to this vehicle gets a COMMAND_ACK:

  =========================  ==============================================================
  DO_SET_MODE, SET_MODE      the rules of :func:`.apm.modes.check_mode_change`
  COMPONENT_ARM_DISARM       arms in STABILIZE / GUIDED / LOITER unless ``refuse_arming`` ("PreArm:"
                             STATUSTEXT, FAILED); disarms on the ground only (or with 21196 force)
  NAV_TAKEOFF                GUIDED, armed, on the ground: climbs to param7 m above home
  NAV_LAND / NAV_RTL         LAND / RTL mode
  MISSION_START (300)        AUTO from param1's item (or the current one)
  DO_SET_MISSION_CURRENT     the current mission item
  DO_REPOSITION (192)        COMMAND_INT, GUIDED (or CHANGE_MODE flag set): flies to x/y/z at param1
                             m/s (WPNAV_SPEED when < 0), yaw param4 degrees (NaN: keep)
  DO_CHANGE_SPEED (178)      param2 m/s for the current leg (AUTO or a reposition)
  DO_DIGICAM_CONTROL         param5 = 1: a shot, CAMERA_FEEDBACK (capture id in param6, :mod:`.apm.items`)
  the requests above         as described
  anything else              MAV_RESULT_UNSUPPORTED
  =========================  ==============================================================

- **Parameters** (:mod:`.apm.params`), SYSID_THISMAV (4.7: MAV_SYSID) = ``uav``, in the names and
  units of ``firmware`` (4.6 or 4.7); an unknown name is answered with PARAM_ERROR (DOES_NOT_EXIST).
  **Missions, fences, rally points**
  (:mod:`.apm.missions`: the mission commands and frames ArduCopter's firmware accepts, the
  firmware's download quirks, MISSION_REQUEST instead of MISSION_REQUEST_INT with
  ``legacy_mission_request``); AUTO flies the mission (:mod:`.apm.auto`: waypoints, loiters,
  delays, DO_JUMP; the items that drive no flight are skipped) with MISSION_CURRENT and
  MISSION_ITEM_REACHED, and CAMERA_FEEDBACK for each shot.
- **GUIDED**, airborne, follows SET_POSITION_TARGET_LOCAL_NED (MAV_FRAME_LOCAL_NED) as ArduCopter's
  guided position/velocity/acceleration controller: the target moves on with its velocity and
  acceleration until 3 s pass without a new one, then the last position is held; a velocity-only
  target starts from the current position; an ignored yaw keeps the heading; a target during the
  takeoff climb ends the climb.
- **GCS failsafe** (FS_GCS_ENABLE, FS_GCS_TIMEOUT): armed and flying, once a HEARTBEAT from
  SYSID_MYGCS has been heard, none for FS_GCS_TIMEOUT s (wall clock) switches to the action's mode
  (1 RTL, 2 RTL unless in AUTO, 3/6 RTL, 4/5 LAND, 7 BRAKE) with "GCS Failsafe" STATUSTEXT;
  a HEARTBEAT clears it. **Fence** (FENCE_ENABLE, FENCE_TYPE bits 1 max altitude, 2 circle about
  home, 4 inclusion polygons of the uploaded fence): a breach sends "Fence Breached", clears the
  geofence health bit and takes FENCE_ACTION (0 report, 1/3/5 RTL, 2 LAND, 4 BRAKE) once.
- **Signing** (``mavlink_key``): MAVLink 2 signing in and out, signature checked before the
  stream timestamp (:mod:`.apm.signing`); unsigned packets are dropped.
- disarms on the ground after landing and DISARM_DELAY s after arming without a takeoff.
- :meth:`MavlinkSimVehicle.pilot_mode` flips the mode as the pilot's remote control would.

Not simulated: MAVLink FTP, RC channels, SmartRTL (its failsafe choices use RTL), terrain. RTL climbs
to RTL_ALT above home (or stays higher), flies home and lands, as ArduCopter's RTL does.
As the firmware, STATUSTEXT is sent only once the link has carried a packet from a peer, and a
mission upload while booting is answered MAV_MISSION_NO_SPACE. Still unlike it: stream rates are
one set for every peer (the firmware keeps them per link); only the parameters the project
uses follow 4.7's renames (:data:`.apm.params.RENAMED`).
With no RC input LOITER (a stick mode) follows the resting sticks as the firmware does: it holds the
position and descends at the throttle-down rate (PILOT_SPEED_DN's default, 2.5 m/s) until it lands.
"""

from .cli import DEFAULT_ORIGIN, build_parser, main
from .commands import GUIDED_TIMEOUT_S, GuidedTarget
from .vehicle import MavlinkSimVehicle

__all__ = ["GuidedTarget", "MavlinkSimVehicle", "GUIDED_TIMEOUT_S", "DEFAULT_ORIGIN", "build_parser", "main"]
