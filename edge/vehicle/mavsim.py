"""The sim autopilot: a MAVLink 2 vehicle that behaves like ArduCopter, flown by the project's simulation.

ArduPilot SITL cannot be fetched here, so :class:`MavlinkSimVehicle` stands in for ArduCopter 4.5
towards real ground stations (QGroundControl, Mission Planner, MAVProxy, MAVSDK) and towards
:class:`edge.vehicle.mavlink.MavlinkDriver`, with :class:`edge.vehicle.sim.SimDriver` (6-DoF plant
(P10)-(P12), PID position loop, ATSM attitude loop (P13)-(P17)) flying underneath. The rules live in
pure modules (:mod:`edge.vehicle.apm`: modes, params, streams, missions, auto, signing); this module
is the socket shell. It runs in a thread (tests), as ``python -m edge.vehicle.mavsim`` or as
``skynet sim-autopilot`` (several instances with distinct ``--uav`` = system ids)::

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
  (:mod:`.apm.missions`); AUTO flies the mission (:mod:`.apm.auto`) with MISSION_CURRENT and
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
uses follow 4.7's renames (:data:`.apm.params.RENAMED`);
LOITER holds altitude (the firmware follows the RC sticks).
"""

from __future__ import annotations

import argparse
import math
import queue
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

import pymap3d
from pymavlink.dialects.v20 import ardupilotmega as M

from edge.clock import SimClock
from edge.vehicle.angles import wrap_angle
from edge.vehicle.apm import items as I
from edge.vehicle.apm.auto import AutoMission, Flight
from edge.vehicle.apm.boot import BootTimeline
from edge.vehicle.apm.missions import FENCE, MISSION, MissionServer, PlanItem, item_from_message
from edge.vehicle.apm.modes import ARMABLE, FENCE_ACTIONS, FS_GCS_ACTIONS, CopterMode, base_mode, check_mode_change
from edge.vehicle.apm.params import DEFAULT_SCHEME, SCHEMES, ParamTable, flight_sw_version, param_name
from edge.vehicle.apm.signing import enable_signing, parse_key
from edge.vehicle.apm.streams import ARDUCOPTER_RATES, DEFAULT_RATES, StreamScheduler
from edge.vehicle.driver import check_vec3
from edge.vehicle.follower import Reference
from edge.vehicle.mavlink import open_connection
from edge.vehicle.quadrotor import DisturbanceParams
from edge.vehicle.sim import SimDriver, SimParams
from protocol.messages import Mode
from protocol.signals import stop_event_on_signals

__all__ = ["GuidedTarget", "MavlinkSimVehicle", "GUIDED_TIMEOUT_S", "DEFAULT_ORIGIN", "main"]

Vec3 = tuple[float, float, float]

#: a guided velocity target older than this is dropped (ArduCopter's guided pos/vel timeout), s
GUIDED_TIMEOUT_S = 3.0
#: ArduPilot's "force" code in param2 of COMPONENT_ARM_DISARM
FORCE_CODE = 21196
#: the scenario's geodetic origin (services/planner/scenarios/monorail.toml): lat, lon (deg), alt (m)
DEFAULT_ORIGIN: Vec3 = (-33.87601, 151.191182, 0.0)
#: ArduCopter 4.5.7, FIRMWARE_VERSION_TYPE_OFFICIAL
FLIGHT_SW_VERSION = (4 << 24) | (5 << 16) | (7 << 8) | 255
CAPABILITIES = (M.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | M.MAV_PROTOCOL_CAPABILITY_MISSION_INT | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE | M.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY)
_SENSORS = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL | M.MAV_SYS_STATUS_SENSOR_3D_MAG
            | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | M.MAV_SYS_STATUS_SENSOR_GPS | M.MAV_SYS_STATUS_AHRS
            | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | M.MAV_SYS_STATUS_SENSOR_BATTERY)
_ON_GROUND = (Mode.IDLE, Mode.LANDED)
_STREAM_IDS = {n: getattr(M, f"MAVLINK_MSG_ID_{n}") for n in (
    "HEARTBEAT", "SYS_STATUS", "GPS_RAW_INT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "VFR_HUD",
    "BATTERY_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION", "MISSION_CURRENT", "EKF_STATUS_REPORT")}
#: ArduPilot repeats failing pre-arm checks as STATUSTEXT this often while disarmed, s
PREARM_REPORT_S = 30.0
_ZERO: Vec3 = (0.0, 0.0, 0.0)


class _CommandInt:
    """A COMMAND_INT seen as a COMMAND_LONG (param5..7 = x, y, z) for the shared command handler."""

    def __init__(self, m: Any):
        self.command, self.frame = m.command, m.frame
        self.param1, self.param2, self.param3, self.param4 = m.param1, m.param2, m.param3, m.param4
        self.param5, self.param6, self.param7 = float(m.x), float(m.y), m.z
        self.x, self.y, self.z = m.x, m.y, m.z


@dataclass(frozen=True)
class GuidedTarget:
    """A guided position target, as ArduCopter's guided position/velocity/acceleration controller flies it.

    Position ``p``, velocity ``v``, acceleration ``a`` (ENU m, m/s, m/s²) and yaw (rad), set at
    sim time ``t_set``. Called at time t it moves on by constant-acceleration kinematics for
    ``k = t − t_set``: ``p + v k + a k²/2``, velocity ``v + a k`` and acceleration ``a`` as
    feed-forward, until ``k`` reaches GUIDED_TIMEOUT_S; then the position stays and the
    feed-forward is dropped. Handed to :meth:`SimDriver.set_external_reference`.
    """

    pos: Vec3
    vel: Vec3
    acc: Vec3
    yaw: float
    t_set: float

    def __call__(self, t: float) -> Reference:
        p, v, a = self.pos, self.vel, self.acc
        age = t - self.t_set
        k = min(max(age, 0.0), GUIDED_TIMEOUT_S)
        h = 0.5 * k * k
        pos = (p[0] + v[0] * k + a[0] * h, p[1] + v[1] * k + a[1] * h, p[2] + v[2] * k + a[2] * h)
        if age >= GUIDED_TIMEOUT_S:
            return pos, _ZERO, _ZERO, self.yaw
        return pos, (v[0] + a[0] * k, v[1] + a[1] * k, v[2] + a[2] * k), a, self.yaw


class MavlinkSimVehicle:
    """A simulated ArduCopter on a MAVLink connection (see the module docstring).

    Parameters
    ----------
    connection : str
        pymavlink connection string (``udpout:host:port`` to reach a ground station or driver
        listening with ``udpin``; ``udpin:host:port`` to be dialled).
    uav : int
        UAV id = MAVLink system id (SYSID_THISMAV).
    home : (x, y, z)
        Launch point, ENU m (the LOCAL_POSITION_NED origin and HOME_POSITION).
    speed : float
        Simulation speed factor (simulated seconds per wall second).
    epoch : float or None
        Wall-clock UNIX time of simulated time 0 (share it with the board's clock); None = now.
    params : SimParams
        The simulated vehicle.
    seed : int
        Disturbance seed.
    telemetry_hz : float
        GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE default rate with ``stream_all``, Hz (wall clock).
    refuse_arming : bool
        Refuse COMPONENT_ARM_DISARM(1) with a PreArm STATUSTEXT (can be changed at any time).
    origin : (lat, lon, alt)
        Geodetic point of the ENU frame's origin, degrees and metres.
    mavlink_key : str or None
        MAVLink 2 signing key (64 hex digits or a passphrase); None: unsigned.
    param_overrides : dict
        Initial parameter values (e.g. ``{"FS_GCS_ENABLE": 1}``).
    boot_scale : float
        Start-up times as a fraction of ArduCopter's (:class:`.apm.boot.BootTimeline`): 1 as the
        firmware (the CLI's default), 0 ready at once (this class's default, for embedding).
    stream_all : bool
        Stream the telemetry set unasked (the old stand-in's behaviour) instead of HEARTBEAT only.
    firmware : str
        Parameter naming scheme (:data:`.apm.params.SCHEMES`): "4.6" (stable 4.5/4.6 names, cm and
        cm/s) or "4.7" (4.7+ names, m and m/s); AUTOPILOT_VERSION reports a matching version.
    """

    def __init__(
        self,
        connection: str,
        uav: int,
        home: Vec3 = (0.0, 0.0, 0.0),
        speed: float = 1.0,
        *,
        epoch: float | None = None,
        params: SimParams = SimParams(),
        seed: int = 0,
        telemetry_hz: float = 20.0,
        refuse_arming: bool = False,
        origin: Vec3 = DEFAULT_ORIGIN,
        mavlink_key: str | None = None,
        param_overrides: dict[str, float] | None = None,
        boot_scale: float = 0.0,
        stream_all: bool = False,
        firmware: str = DEFAULT_SCHEME,
    ):
        if not (isinstance(uav, int) and 1 <= uav <= 255):
            raise ValueError("uav must be an int in 1..255")
        if not (isinstance(telemetry_hz, (int, float)) and math.isfinite(telemetry_hz) and 0 < telemetry_hz <= 100):
            raise ValueError("telemetry_hz must be in (0, 100]")
        o = check_vec3(origin, "origin")
        if abs(o[0]) > 90 or abs(o[1]) > 180:
            raise ValueError("origin must be (lat, lon, alt) in degrees and metres")
        self.boot = BootTimeline(scale=boot_scale)
        self.uav = uav
        self.home = check_vec3(home, "home")
        self.origin = o
        self.clock = SimClock(epoch=epoch, speed=speed)
        self.sim = SimDriver(uav, params=params, seed=seed, home=self.home, t0=self.clock.now())
        self._t_boot = self.clock.now()
        self.params = ParamTable(scheme=firmware, **{param_name("sysid", firmware): uav, **(param_overrides or {})})
        self.flight_sw_version = FLIGHT_SW_VERSION if firmware == "4.6" else flight_sw_version(firmware)
        self.home_lla = self.enu_to_lla(self.home)
        rates = dict(DEFAULT_RATES if stream_all else ARDUCOPTER_RATES)
        if stream_all:
            for n in ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE"):
                rates[n] = float(telemetry_hz)
        self.streams = StreamScheduler(_STREAM_IDS, rates)
        self.missions = MissionServer(home=self._home_item)
        self._conn = open_connection(connection, uav, M.MAV_COMP_ID_AUTOPILOT1)
        if mavlink_key is not None:
            enable_signing(self._conn, parse_key(mavlink_key))
        self.connection = connection
        self.custom_mode = CopterMode.STABILIZE
        self.armed = False
        self.refuse_arming = bool(refuse_arming)
        self.prearm_text = "PreArm: arming refused by the simulator (refuse_arming)"
        self._armed_at = 0.0
        self._was_airborne = False
        self._boot_seen = -math.inf  # boot time up to which the start-up STATUSTEXTs were sent
        self._peer_heard = False  # a packet arrived on the link (STATUSTEXT goes only to such links)
        self._prearm_sent = -math.inf
        #: camera shots (capture ids, DO_DIGICAM_CONTROL param6), commands answered (command, result)
        self.shots: list[int] = []
        self.commands: list[tuple[int, int]] = []
        self.reached: list[int] = []
        self.statustexts: list[str] = []
        self.targets_received = 0
        self.gcs_heartbeats = 0
        self.errors: list[str] = []
        self.auto: AutoMission | None = None
        self._leg: AutoMission | None = None  # a DO_REPOSITION in GUIDED
        self._gcs_mono: float | None = None
        self.gcs_failsafe = False
        self.fence_breached = False
        self.fence_breaches = 0
        self._pilot: queue.SimpleQueue[int] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    # ------------------------------------------------------------------ geodesy
    def enu_to_lla(self, p: Vec3) -> Vec3:
        lat, lon, h = pymap3d.enu2geodetic(p[0], p[1], p[2], *self.origin)
        return float(lat), float(lon), float(h)

    def item_enu(self, it: PlanItem) -> Vec3:
        """ENU position of a positioned item (relative frames: altitude above home)."""
        lat, lon = it.x / 1e7, it.y / 1e7
        alt = it.z + (self.home_lla[2] if it.frame in (I.MAV_FRAME_GLOBAL_RELATIVE_ALT, 6) else 0.0)
        e, n, u = pymap3d.geodetic2enu(lat, lon, alt, *self.origin)
        return float(e), float(n), float(u)

    def _home_item(self) -> PlanItem:
        lat, lon, h = self.home_lla
        return PlanItem(0, I.MAV_FRAME_GLOBAL, I.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0,
                        round(lat * 1e7), round(lon * 1e7), h)

    # ------------------------------------------------------------------ running
    def start(self) -> MavlinkSimVehicle:
        """Run in a daemon thread (stop with :meth:`close`)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.run, name=f"mavsim-uav{self.uav}", daemon=True)
            self._thread.start()
        return self

    def run(self, stop: threading.Event | None = None) -> None:
        """Serve until :meth:`close` (or ``stop`` is set)."""
        while not self._stop.is_set() and not (stop is not None and stop.is_set()):
            self.poll()
            self._conn.select(0.005)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        try:
            self._conn.close()
        except OSError:
            pass

    def __enter__(self) -> MavlinkSimVehicle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def pilot_mode(self, mode: int) -> None:
        """Flip the mode as the pilot's remote control would (thread-safe; applied at the next poll)."""
        self._pilot.put(int(mode))

    def poll(self) -> None:
        """One pass: handle the pending messages, advance the simulation to now, send due telemetry."""
        while not self._pilot.empty():
            if self._set_mode(self._pilot.get()) != M.MAV_RESULT_ACCEPTED:
                self.errors.append("pilot mode change refused")
            self.send_heartbeat()  # show the new mode now, not at the next 1 Hz heartbeat
        for _ in range(200):
            try:
                msg = self._conn.recv_msg()
            except Exception as exc:  # a malformed datagram must not stop the vehicle
                self.errors.append(f"receive: {exc}")
                break
            if msg is None:
                break
            try:
                self._handle(msg)
            except Exception as exc:  # a message with odd values must not stop the vehicle
                self.errors.append(f"{msg.get_type()}: {exc!r}")
        now = time.monotonic()
        self._out(self.missions.tick(now))
        self._fly()
        try:
            self.sim.step(self.clock.now())
        except ValueError as exc:
            self.errors.append(f"step: {exc}")
        self._after_step(now)
        self._startup_texts()
        for name in self.streams.due(now):
            self._stream(name)

    @property
    def airborne(self) -> bool:
        return self.sim.mode not in _ON_GROUND

    # ------------------------------------------------------------------ start-up (apm.boot)
    def boot_time(self) -> float:
        """Simulated seconds since power-on."""
        return self.clock.now() - self._t_boot

    @property
    def home_known(self) -> bool:
        return self.boot.home_known(self.boot_time())

    @property
    def position_ok(self) -> bool:
        return self.boot.position(self.boot_time())

    def _startup_texts(self) -> None:
        """The EKF's start-up STATUSTEXTs, and the failing pre-arm check every PREARM_REPORT_S while disarmed."""
        t = self.boot_time()
        if self.boot.booting(t):
            return
        for text in self.boot.texts_between(self._boot_seen, t):
            self._text(M.MAV_SEVERITY_INFO, text)
        self._boot_seen = t
        why = self.boot.prearm_failure(t)
        if why is not None and not self.armed and t - self._prearm_sent >= PREARM_REPORT_S:
            self._prearm_sent = t
            self._text(M.MAV_SEVERITY_CRITICAL, f"PreArm: {why}")

    def _after_step(self, now: float) -> None:
        sim = self.sim
        airborne = self.airborne
        if self.armed and self._was_airborne and not airborne:
            self.armed = False  # ArduCopter disarms once landed (and stays in LAND / RTL / AUTO)
        if self.armed and not airborne and sim.t - self._armed_at > self.params["DISARM_DELAY"] > 0:
            self.armed = False  # armed on the ground without taking off
        self._was_airborne = airborne
        self._failsafe_gcs(now)
        self._fence()

    # ------------------------------------------------------------------ AUTO and reposition
    def _fly(self) -> None:
        """Let AUTO (or a GUIDED reposition) choose the simulated vehicle's reference for this pass."""
        ex = self.auto if self.custom_mode == CopterMode.AUTO else self._leg if self.custom_mode == CopterMode.GUIDED \
            else None
        if ex is None or (not self.armed and not self.airborne and ex.current in (0, 1)):
            return  # waiting on the ground for the arming
        sim = self.sim
        st = sim.state()
        fl, events = ex.update(sim.t, st.pos, st.att[2], self.airborne)
        for kind, v in events:
            if kind == "reached" and ex is self.auto:
                self.reached.append(v)
                self._send("mission_item_reached_send", v)
            elif kind == "current" and ex is self.auto:
                self._stream("MISSION_CURRENT")
            elif kind == "shot":
                self._shot(v, st)
        try:
            self._apply(fl, st)
        except ValueError as exc:
            self.errors.append(f"auto: {exc}")
        if ex is self._leg and ex.done:
            self._leg = None

    def _apply(self, fl: Flight, st: Any) -> None:
        sim = self.sim
        if fl.kind == "takeoff":
            if sim.mode in _ON_GROUND:
                if self.armed:
                    sim.takeoff(fl.alt)
            elif sim.mode == Mode.HOLD:  # airborne below the item's altitude: climb where it is
                sim.set_external_reference(GuidedTarget(fl.pos, _ZERO, _ZERO, fl.yaw, sim.t))
        elif fl.kind == "land":
            if sim.mode not in (Mode.LAND, *_ON_GROUND):
                sim.land()
        elif fl.kind == "rtl":
            if sim.mode not in (Mode.RTL, Mode.LAND, *_ON_GROUND):
                sim.return_to_launch()
        elif fl.kind in ("goto", "hold") and self.airborne:
            if sim.mode == Mode.TAKEOFF:
                if fl.kind == "hold":
                    return  # let the takeoff climb finish
                sim.hold()
            if sim.mode != Mode.HOLD:
                return
            sim.set_external_reference(GuidedTarget(fl.pos, fl.vel, _ZERO, fl.yaw, sim.t))

    def _shot(self, capture_id: int, st: Any) -> None:
        self.shots.append(capture_id)
        lat, lon, h = self.enu_to_lla(st.pos)
        r = st.att
        self._send("camera_feedback_send", int(time.time() * 1e6), 0, 0, len(self.shots) - 1,
                   round(lat * 1e7), round(lon * 1e7), h, st.pos[2] - self.home[2], math.degrees(r[0]),
                   -math.degrees(r[1]), math.degrees(wrap_angle(math.pi / 2 - r[2])) % 360.0, 0.0, 1, len(self.shots))

    # ------------------------------------------------------------------ failsafes
    def _failsafe_gcs(self, now: float) -> None:
        action = int(self.params["FS_GCS_ENABLE"])
        if self._gcs_mono is None or action == 0 or not (self.armed and self.airborne):
            return
        lost = now - self._gcs_mono > self.params["FS_GCS_TIMEOUT"]
        if lost and not self.gcs_failsafe:
            self.gcs_failsafe = True
            self._text(M.MAV_SEVERITY_CRITICAL, "GCS Failsafe")
            if not (action == 2 and self.custom_mode == CopterMode.AUTO):
                self._set_mode(FS_GCS_ACTIONS.get(action, CopterMode.RTL))
                self.send_heartbeat()
        elif not lost and self.gcs_failsafe:
            self.gcs_failsafe = False
            self._text(M.MAV_SEVERITY_CRITICAL, "GCS Failsafe Cleared")

    def _fence_breach(self, pos: Vec3) -> bool:
        kinds = int(self.params["FENCE_TYPE"])
        h = self.home
        if kinds & 1 and pos[2] - h[2] > self.params["FENCE_ALT_MAX"]:
            return True
        if kinds & 2 and math.hypot(pos[0] - h[0], pos[1] - h[1]) > self.params["FENCE_RADIUS"]:
            return True
        if kinds & 4:
            poly = [self.item_enu(it) for it in self.missions.stores[FENCE]
                    if it.command == I.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION]
            if len(poly) >= 3 and not _inside(pos, poly):
                return True
        return False

    def _fence(self) -> None:
        if not self.params["FENCE_ENABLE"] or not (self.armed and self.airborne):
            self.fence_breached = False
            return
        breach = self._fence_breach(self.sim.state().pos)
        if breach and not self.fence_breached:
            self.fence_breached = True
            self.fence_breaches += 1
            self._text(M.MAV_SEVERITY_CRITICAL, "Fence Breached")
            mode = FENCE_ACTIONS.get(int(self.params["FENCE_ACTION"]))
            if mode is not None and mode != self.custom_mode:
                self._set_mode(mode)
                self.send_heartbeat()
        elif not breach:
            self.fence_breached = False

    # ------------------------------------------------------------------ output
    def _boot_ms(self) -> int:
        return int(max(0.0, self.clock.now() - self._t_boot) * 1000) & 0xFFFFFFFF

    def _send(self, name: str, *args: Any, **kw: Any) -> None:
        try:
            getattr(self._conn.mav, name)(*args, **kw)
        except (OSError, ValueError, TypeError, OverflowError) as exc:  # struct.error is a ValueError... mostly
            self.errors.append(f"send {name}: {exc}")
        except Exception as exc:  # struct.error
            self.errors.append(f"send {name}: {exc}")

    def _out(self, outs: list[tuple[str, dict]]) -> None:
        for name, fields in outs:
            self._send(name + "_send", **fields)

    def _landed_state(self) -> int:
        m = self.sim.mode
        if m in _ON_GROUND:
            return M.MAV_LANDED_STATE_ON_GROUND
        if m == Mode.TAKEOFF:
            return M.MAV_LANDED_STATE_TAKEOFF
        if m == Mode.LAND:
            return M.MAV_LANDED_STATE_LANDING
        return M.MAV_LANDED_STATE_IN_AIR

    def _stream(self, name: str) -> bool:
        """Send one message of the telemetry set by name; False when this vehicle does not produce it."""
        h = self.home
        if name == "HEARTBEAT":
            self.send_heartbeat()
            return True
        if name == "AUTOPILOT_VERSION":
            self._send("autopilot_version_send", CAPABILITIES, self.flight_sw_version, 0, 0, 0, [0] * 8, [0] * 8,
                       [0] * 8, 0x1209, 0x5740, self.uav)
            return True
        if name not in _STREAM_IDS:
            return False
        st = self.sim.state()
        ms = self._boot_ms()
        p, v = st.pos, st.vel
        home = self.home_known
        if name in ("LOCAL_POSITION_NED", "HOME_POSITION") and not home:
            return True  # no EKF origin yet: ArduPilot sends neither
        if name == "EKF_STATUS_REPORT":
            flags = self.boot.ekf_flags(self.boot_time())
            var = 0.02 if flags & 16 else 0.5
            self._send("ekf_status_report_send", flags, var, var, 0.02, 0.02, 0.0, 0.0)
        elif name == "LOCAL_POSITION_NED":
            self._send("local_position_ned_send", ms, p[1] - h[1], p[0] - h[0], -(p[2] - h[2]), v[1], v[0], -v[2])
        elif name == "ATTITUDE":
            r, q = st.att, st.rates
            self._send("attitude_send", ms, r[0], -r[1], wrap_angle(math.pi / 2 - r[2]), q[0], -q[1], -q[2])
        elif name == "SYS_STATUS":
            present = _SENSORS | M.MAV_SYS_STATUS_GEOFENCE | M.MAV_SYS_STATUS_PREARM_CHECK
            enabled = _SENSORS | M.MAV_SYS_STATUS_PREARM_CHECK | (
                M.MAV_SYS_STATUS_GEOFENCE if self.params["FENCE_ENABLE"] else 0)
            armable = not self.refuse_arming and self.boot.prearm_failure(self.boot_time()) is None
            health = _SENSORS | (0 if self.fence_breached else M.MAV_SYS_STATUS_GEOFENCE) | (
                M.MAV_SYS_STATUS_PREARM_CHECK if armable else 0)
            pct = int(round(100 * min(1.0, max(0.0, st.battery))))
            self._send("sys_status_send", present, enabled, health, 100, self._voltage_mv(st), 150, pct,
                       0, 0, 0, 0, 0, 0)
        elif name in ("GLOBAL_POSITION_INT", "GPS_RAW_INT", "VFR_HUD"):
            lat, lon, alt = self.enu_to_lla(p)
            hdg = math.degrees(wrap_angle(math.pi / 2 - st.att[2])) % 360.0
            gs = math.hypot(v[0], v[1])
            if not home:  # ArduPilot sends the (unset, zero) location before the EKF has an origin
                lat = lon = alt = 0.0
            if name == "GLOBAL_POSITION_INT":
                self._send("global_position_int_send", ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
                           round((p[2] - h[2]) * 1000), round(v[1] * 100), round(v[0] * 100), round(-v[2] * 100),
                           round(hdg * 100) % 36000)
            elif name == "GPS_RAW_INT":
                cog = round(math.degrees(math.atan2(v[0], v[1])) % 360.0 * 100) % 36000 if gs > 0.2 else 65535
                self._send("gps_raw_int_send", int(time.time() * 1e6), M.GPS_FIX_TYPE_3D_FIX, round(lat * 1e7),
                           round(lon * 1e7), round(alt * 1000), 80, 120, round(gs * 100), cog, 12)
            else:
                self._send("vfr_hud_send", gs, gs, round(hdg) % 360, 50 if self.airborne else 0, alt, v[2])
        elif name == "BATTERY_STATUS":
            cells = [self._voltage_mv(st) // 4] * 4 + [65535] * 6
            self._send("battery_status_send", 0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 32767, cells,
                       150, -1, -1, int(round(100 * min(1.0, max(0.0, st.battery)))))
        elif name == "EXTENDED_SYS_STATE":
            self._send("extended_sys_state_send", M.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        elif name == "HOME_POSITION":
            lat, lon, alt = self.home_lla
            self._send("home_position_send", round(lat * 1e7), round(lon * 1e7), round(alt * 1000), 0.0, 0.0, 0.0,
                       [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)
        elif name == "MISSION_CURRENT":
            n = len(self.missions.stores[MISSION])
            a = self.auto
            seq = a.current if a is not None else 0
            state = (M.MISSION_STATE_NO_MISSION if n <= 1 else M.MISSION_STATE_COMPLETE if a is not None and a.done
                     else M.MISSION_STATE_ACTIVE if self.custom_mode == CopterMode.AUTO
                     else M.MISSION_STATE_NOT_STARTED if a is None else M.MISSION_STATE_PAUSED)
            self._send("mission_current_send", min(seq, max(0, n - 1)) if n else 0, n, state,
                       1 if self.custom_mode == CopterMode.AUTO else 0)
        return True

    @staticmethod
    def _voltage_mv(st: Any) -> int:
        return int(15000 + 1800 * min(1.0, max(0.0, st.battery)))

    def send_heartbeat(self) -> None:
        flying = self.airborne
        base = base_mode(self.custom_mode, armed=self.armed, flying=flying)
        status = (M.MAV_STATE_CRITICAL if self.gcs_failsafe else M.MAV_STATE_BOOT if self.boot.booting(self.boot_time())
                  else M.MAV_STATE_ACTIVE if flying else M.MAV_STATE_STANDBY)
        self._send("heartbeat_send", M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                   int(self.custom_mode), status)

    def _text(self, severity: int, text: str) -> None:
        """A STATUSTEXT, sent (as by the firmware) only once the link has carried a packet from a peer."""
        self.statustexts.append(text)
        if self._peer_heard:
            self._send("statustext_send", severity, text.encode()[:50])

    # ------------------------------------------------------------------ input
    def _for_me(self, msg: Any) -> bool:
        return msg.target_system in (0, self.uav)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind != "BAD_DATA":
            self._peer_heard = True
        if kind == "HEARTBEAT":
            if msg.type == M.MAV_TYPE_GCS:
                self.gcs_heartbeats += 1
            if src[0] == int(self.params[self.params.name("gcs_sysid")]):
                self._gcs_mono = time.monotonic()
            return
        if kind == "BAD_DATA" or not hasattr(msg, "target_system") or not self._for_me(msg):
            return
        now = time.monotonic()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            m = msg if kind == "COMMAND_LONG" else _CommandInt(msg)
            result = self._command(m, kind == "COMMAND_INT")
            self.commands.append((int(msg.command), result))
            self._send("command_ack_send", msg.command, result, 0, 0, src[0], src[1])
        elif kind == "SET_MODE":
            ok = msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            result = self._set_mode(msg.custom_mode) if ok else M.MAV_RESULT_UNSUPPORTED
            self._send("command_ack_send", M.MAVLINK_MSG_ID_SET_MODE, result, 0, 0, src[0], src[1])
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._position_target(msg)
        elif kind == "PARAM_REQUEST_LIST":
            self._out(self.params.request_list())
        elif kind == "PARAM_REQUEST_READ":
            self._out(self.params.request_read(msg.param_id, msg.param_index, src))
        elif kind == "PARAM_SET":
            self._out(self.params.param_set(msg.param_id, msg.param_value, src))
        elif kind == "REQUEST_DATA_STREAM":
            self.streams.request_data_stream(msg.req_stream_id, msg.req_message_rate, msg.start_stop)
        elif kind == "MISSION_COUNT":
            if self.boot.booting(self.boot_time()):  # the firmware's mission storage is not up yet
                self._send("mission_ack_send", src[0], src[1], M.MAV_MISSION_NO_SPACE, msg.mission_type)
                return
            self._out(self.missions.count(src, msg.mission_type, msg.count, now))
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            int_msg = kind == "MISSION_ITEM_INT"
            self._out(self.missions.item(src, item_from_message(msg, int_msg), int_msg, now))
        elif kind == "MISSION_REQUEST_LIST":
            self._out(self.missions.request_list(src, msg.mission_type))
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._out(self.missions.request(src, msg.mission_type, msg.seq, kind == "MISSION_REQUEST_INT"))
        elif kind == "MISSION_CLEAR_ALL":
            self._out(self.missions.clear(src, msg.mission_type))
            if msg.mission_type in (MISSION, 255):
                self.auto = None
        elif kind == "MISSION_SET_CURRENT":
            self._set_current(msg.seq)

    def _set_current(self, seq: float) -> bool:
        items = self.missions.mission()
        if not (math.isfinite(seq) and 1 <= seq < len(items)):
            return False
        if self.auto is None:
            self.auto = self._new_auto(int(seq))
        else:
            self.auto.set_current(int(seq))
        self._stream("MISSION_CURRENT")
        return True

    def _new_auto(self, start: int = 1) -> AutoMission:
        return AutoMission(self.missions.mission(), self.item_enu, self.home, self.params.si("wp_speed"),
                           radius=self.params.si("wp_radius"), yaw_behavior=0, start=start)

    def _command(self, msg: Any, is_int: bool) -> int:
        c = msg.command
        if c == M.MAV_CMD_DO_SET_MODE:
            if not int(msg.param1) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return M.MAV_RESULT_UNSUPPORTED
            return self._set_mode(msg.param2)
        if c == M.MAV_CMD_COMPONENT_ARM_DISARM:
            return self._arm(msg.param1 > 0.5, int(msg.param2) == FORCE_CODE)
        if c == M.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(msg.param7)
        if c == M.MAV_CMD_NAV_LAND:
            return self._set_mode(CopterMode.LAND)
        if c == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode(CopterMode.RTL)
        if c == M.MAV_CMD_MISSION_START:
            first = int(msg.param1) if math.isfinite(msg.param1) and msg.param1 >= 1 else None
            r = self._set_mode(CopterMode.AUTO)
            if r == M.MAV_RESULT_ACCEPTED and first is not None:
                self._set_current(first)
            return r
        if c == M.MAV_CMD_DO_SET_MISSION_CURRENT:
            return M.MAV_RESULT_ACCEPTED if self._set_current(msg.param1) else M.MAV_RESULT_DENIED
        if c == M.MAV_CMD_DO_REPOSITION:
            return self._reposition(msg, is_int)
        if c == M.MAV_CMD_DO_CHANGE_SPEED:
            ex = self.auto if self.custom_mode == CopterMode.AUTO else self._leg
            if not (math.isfinite(msg.param2) and 0 < msg.param2 <= 20):
                return M.MAV_RESULT_DENIED
            if ex is not None:
                ex.set_speed(self.sim.t, float(msg.param2))
            return M.MAV_RESULT_ACCEPTED
        if c == M.MAV_CMD_DO_DIGICAM_CONTROL:
            cid = I.capture_id((msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7))
            if msg.param5 == 1:
                self._shot(cid if cid is not None else len(self.shots), self.sim.state())
            return M.MAV_RESULT_ACCEPTED
        if c == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            return M.MAV_RESULT_ACCEPTED if self.streams.set_interval(msg.param1, msg.param2) else M.MAV_RESULT_DENIED
        if c == M.MAV_CMD_GET_MESSAGE_INTERVAL:
            us = self.streams.interval_us(msg.param1)
            if us is None:
                return M.MAV_RESULT_DENIED
            self._send("message_interval_send", int(msg.param1), us)
            return M.MAV_RESULT_ACCEPTED
        if c == M.MAV_CMD_REQUEST_MESSAGE:
            if not math.isfinite(msg.param1):
                return M.MAV_RESULT_DENIED
            mid = int(msg.param1)
            name = "AUTOPILOT_VERSION" if mid == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION else self.streams.names.get(mid)
            return M.MAV_RESULT_ACCEPTED if name is not None and self._stream(name) else M.MAV_RESULT_DENIED
        if c == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._stream("AUTOPILOT_VERSION")
            return M.MAV_RESULT_ACCEPTED
        if c == M.MAV_CMD_GET_HOME_POSITION:
            if not self.home_known:
                return M.MAV_RESULT_FAILED
            self._stream("HOME_POSITION")
            return M.MAV_RESULT_ACCEPTED
        return M.MAV_RESULT_UNSUPPORTED

    def _reposition(self, msg: Any, is_int: bool) -> int:
        """DO_REPOSITION: GUIDED (or CHANGE_MODE) and airborne; x, y lat/lon (×1e7 in COMMAND_INT), z altitude."""
        if not is_int or not (self.armed and self.airborne):
            return M.MAV_RESULT_DENIED if is_int else M.MAV_RESULT_UNSUPPORTED
        if self.custom_mode != CopterMode.GUIDED:
            if not int(msg.param2) & M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE:
                return M.MAV_RESULT_DENIED
            if self._set_mode(CopterMode.GUIDED) != M.MAV_RESULT_ACCEPTED:
                return M.MAV_RESULT_FAILED
        frame = {M.MAV_FRAME_GLOBAL_INT: I.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT:
                 I.MAV_FRAME_GLOBAL_RELATIVE_ALT}.get(msg.frame, msg.frame)
        if frame not in (I.MAV_FRAME_GLOBAL, I.MAV_FRAME_GLOBAL_RELATIVE_ALT) or not math.isfinite(msg.z):
            return M.MAV_RESULT_DENIED
        it = PlanItem(1, frame, I.MAV_CMD_NAV_WAYPOINT, x=int(msg.x), y=int(msg.y), z=float(msg.z))
        speed = msg.param1 if math.isfinite(msg.param1) and msg.param1 > 0 else self.params.si("wp_speed")
        leg = AutoMission([self._home_item(), it], self.item_enu, self.home, speed,
                          radius=self.params.si("wp_radius"), yaw_behavior=0)
        if math.isfinite(msg.param4):
            leg._yaw = wrap_angle(math.radians(90.0 - msg.param4))
        self._hold_here()
        self._leg = leg
        return M.MAV_RESULT_ACCEPTED

    def _hold_here(self) -> None:
        sim = self.sim
        if sim.mode != Mode.HOLD:
            sim.hold()  # from TAKEOFF, MISSION, LAND, RTL: hold where it is (drops a guided target)
        else:
            s = sim.state()
            sim.set_external_reference(GuidedTarget(s.pos, _ZERO, _ZERO, s.att[2], sim.t))

    def _set_mode(self, mode: float) -> int:
        items = self.missions.mission()
        first_nav = next((it.command for it in items[1:] if it.command in (16, 20, 21, 22)), None)
        m, why = check_mode_change(mode, airborne=self.airborne, armed=self.armed,
                                   mission_items=max(0, len(items) - 1), first_nav=first_nav,
                                   position_ok=self.position_ok)
        if m is None:
            try:
                name = CopterMode(int(mode)).name
            except (ValueError, OverflowError):
                name = f"{mode:g}"
            self._text(M.MAV_SEVERITY_WARNING, f"Mode change to {name} failed: {why}"[:50])
            return M.MAV_RESULT_FAILED
        sim = self.sim
        prev = self.custom_mode
        try:
            if self.airborne:
                if m in (CopterMode.GUIDED, CopterMode.LOITER, CopterMode.BRAKE):
                    if m != prev or m != CopterMode.GUIDED:
                        self._hold_here()
                        self._leg = None
                elif m == CopterMode.LAND:
                    sim.land()
                elif m == CopterMode.RTL:  # ArduCopter's RTL climbs to RTL_ALT (cm) above home first
                    sim.return_to_launch(self.params.si("rtl_alt"))
                elif m == CopterMode.AUTO and prev != CopterMode.AUTO:
                    self._hold_here()
        except ValueError as exc:
            self._text(M.MAV_SEVERITY_WARNING, f"Mode change failed: {exc}"[:50])
            return M.MAV_RESULT_FAILED
        if m == CopterMode.AUTO and prev != CopterMode.AUTO:
            if self.auto is None or self.auto.done or self.auto.items != items:
                start = self.auto.current if self.auto is not None and not self.auto.done \
                    and self.auto.items == items else 1
                self.auto = self._new_auto(start)
            else:
                self.auto = self._new_auto(self.auto.current)  # resumes at the current item
        self.custom_mode = m
        return M.MAV_RESULT_ACCEPTED

    def _arm(self, arm: bool, force: bool) -> int:
        if not arm:
            if self.airborne and not force:
                self._text(M.MAV_SEVERITY_WARNING, "Disarm: vehicle is flying")
                return M.MAV_RESULT_FAILED
            self.armed = False
            return M.MAV_RESULT_ACCEPTED
        if self.armed:
            return M.MAV_RESULT_ACCEPTED
        if self.refuse_arming:
            self._text(M.MAV_SEVERITY_CRITICAL, self.prearm_text)
            return M.MAV_RESULT_FAILED
        why = self.boot.prearm_failure(self.boot_time())
        if why is not None:
            self._text(M.MAV_SEVERITY_CRITICAL, f"Arm: {why}")
            return M.MAV_RESULT_FAILED
        if self.custom_mode not in ARMABLE:
            self._text(M.MAV_SEVERITY_CRITICAL, "Arm: Mode not armable")
            return M.MAV_RESULT_FAILED
        self.armed = True
        self._armed_at = self.sim.t
        return M.MAV_RESULT_ACCEPTED

    def _takeoff(self, altitude: float) -> int:
        if self.custom_mode != CopterMode.GUIDED or not self.armed or self.airborne:
            self._text(M.MAV_SEVERITY_WARNING, "Takeoff: needs GUIDED, armed, on the ground")
            return M.MAV_RESULT_FAILED
        try:
            self.sim.takeoff(altitude)
        except ValueError as exc:
            self._text(M.MAV_SEVERITY_WARNING, f"Takeoff: {exc}"[:50])
            return M.MAV_RESULT_FAILED
        return M.MAV_RESULT_ACCEPTED

    def _position_target(self, msg: Any) -> None:
        sim = self.sim
        if (msg.coordinate_frame != M.MAV_FRAME_LOCAL_NED or self.custom_mode != CopterMode.GUIDED
                or not self.armed or sim.mode not in (Mode.HOLD, Mode.TAKEOFF)):
            return
        mask = msg.type_mask
        use_pos = (mask & 0b111) != 0b111
        use_vel = (mask & 0b111000) != 0b111000
        use_acc = (mask & 0b111000000) != 0b111000000 and not mask & M.POSITION_TARGET_TYPEMASK_FORCE_SET
        if not (use_pos or use_vel):
            return
        vals = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz, msg.afx, msg.afy, msg.afz, msg.yaw)
        if not all(math.isfinite(v) for v in vals):
            return
        if sim.mode == Mode.TAKEOFF:
            sim.hold()  # a target ends the takeoff climb
        self._leg = None
        s = sim.state()
        h = self.home
        pos = (h[0] + msg.y, h[1] + msg.x, h[2] - msg.z) if use_pos else s.pos
        vel = (msg.vy, msg.vx, -msg.vz) if use_vel else _ZERO
        acc = (msg.afy, msg.afx, -msg.afz) if use_acc else _ZERO
        yaw = s.att[2] if mask & M.POSITION_TARGET_TYPEMASK_YAW_IGNORE else wrap_angle(math.pi / 2 - msg.yaw)
        sim.set_external_reference(GuidedTarget(pos, vel, acc, yaw, sim.t))
        self.targets_received += 1


def _inside(p: Vec3, poly: list[Vec3]) -> bool:
    """Point-in-polygon (even-odd rule) in the horizontal plane."""
    x, y = p[0], p[1]
    inside = False
    for (x1, y1, _), (x2, y2, _) in zip(poly, poly[1:] + poly[:1]):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


# ---------------------------------------------------------------------------------- process
def _vec(text: str) -> Vec3:
    try:
        return check_vec3([float(x) for x in text.split(",")], "vector")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers ({exc})") from None


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    try:
        return name.strip().upper(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}") from None


def build_parser(prog: str = "python -m edge.vehicle.mavsim") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("--connection", default="udpout:127.0.0.1:14550",
                   help="pymavlink connection string (udpout:HOST:PORT reaches a GCS listening there)")
    p.add_argument("--uav", type=int, required=True, help="UAV id = MAVLink system id")
    p.add_argument("--home", type=_vec, default=(0.0, 0.0, 0.0), help="launch point x,y,z (ENU m)")
    p.add_argument("--origin", type=_vec, default=DEFAULT_ORIGIN, help="geodetic origin lat,lon,alt of the ENU frame")
    p.add_argument("--speed", type=float, default=1.0, help="simulation speed factor")
    p.add_argument("--epoch", type=float, default=None, help="wall-clock UNIX time of sim time 0")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--wind", choices=["calm", "moderate"], default="calm")
    p.add_argument("--telemetry-hz", type=float, default=20.0)
    p.add_argument("--refuse-arming", action="store_true", help="fail every arming request (PreArm)")
    p.add_argument("--mavlink-key", default=None, help="MAVLink 2 signing key: 64 hex digits or a passphrase")
    p.add_argument("--param", type=_param, action="append", default=[], metavar="NAME=VALUE",
                   help="initial parameter value (repeatable), e.g. FS_GCS_ENABLE=1")
    add_firmware_options(p)
    return p


def add_firmware_options(p: argparse.ArgumentParser) -> None:
    """``--boot-scale`` and ``--stream-all`` (shared with ``skynet sim-autopilot``)."""
    p.add_argument("--boot-scale", type=float, default=1.0,
                   help="start-up times as a fraction of ArduCopter's (1: BOOT 2 s, home 20 s, armable 24 s, "
                        "GUIDED/AUTO 42 s; 0: ready at once)")
    p.add_argument("--stream-all", action="store_true",
                   help="stream telemetry unasked (ArduCopter sends only HEARTBEAT until a ground station asks)")
    p.add_argument("--firmware-version", choices=SCHEMES, default=DEFAULT_SCHEME,
                   help="parameter names and units of this ArduCopter version: 4.6 (stable 4.5/4.6: SYSID_THISMAV, "
                        "WPNAV_SPEED cm/s, RTL_ALT cm, LAND_SPEED, ARMING_CHECK) or 4.7 (4.7+: MAV_SYSID, WP_SPD m/s, "
                        "RTL_ALT_M m, LAND_SPD_MS, ARMING_SKIPCHK, WP_RADIUS_M, MAV_GCS_SYSID)")


def main(argv: list[str] | None = None, prog: str = "python -m edge.vehicle.mavsim") -> int:
    args = build_parser(prog).parse_args(argv)
    wind = DisturbanceParams.moderate() if args.wind == "moderate" else DisturbanceParams()
    try:
        vehicle = MavlinkSimVehicle(args.connection, args.uav, home=args.home, speed=args.speed, epoch=args.epoch,
                                    params=SimParams(disturbance=wind), seed=args.seed,
                                    telemetry_hz=args.telemetry_hz, refuse_arming=args.refuse_arming,
                                    origin=args.origin, mavlink_key=args.mavlink_key,
                                    param_overrides=dict(args.param), boot_scale=args.boot_scale,
                                    stream_all=args.stream_all, firmware=args.firmware_version)
    except ValueError as exc:
        print(f"mavsim: {exc}", file=sys.stderr)
        return 2
    stop = stop_event_on_signals()
    print(f"mavsim up: uav {args.uav} on {args.connection}, speed x{args.speed:g}", flush=True)
    try:
        vehicle.run(stop)
    finally:
        vehicle.close()
    print("mavsim stopped", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
