"""The sim autopilot's vehicle: the link, the table from message type to handler, and the glue to the
simulated vehicle (AUTO and reposition legs, the GCS failsafe, the fence); see the package docstring."""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

import pymap3d
from pymavlink.dialects.v20 import ardupilotmega as M

from edge.clock import SimClock
from edge.geometry import ardupilot_items as I
from edge.vehicle.apm.auto import AutoMission, Flight
from edge.vehicle.apm.boot import BootTimeline
from edge.vehicle.apm.missions import FENCE, MISSION, MissionServer, PlanItem, item_from_message
from edge.vehicle.apm.modes import FENCE_ACTIONS, FS_GCS_ACTIONS, PILOT_DESCENT_MS, STICK_MODES, CopterMode
from edge.vehicle.apm.params import DEFAULT_SCHEME, ParamTable, flight_sw_version, param_name
from edge.vehicle.apm.signing import enable_signing, parse_key
from edge.vehicle.apm.streams import ARDUCOPTER_RATES, DEFAULT_RATES, StreamScheduler
from edge.vehicle.driver import check_vec3
from edge.vehicle.mavlink.link import open_connection
from edge.vehicle.sim import MAX_STEP_S, SimDriver, SimParams
from protocol.messages import Mode

from .commands import GuidedTarget, SimCommands, _CommandInt
from .telemetry import FLIGHT_SW_VERSION, STREAM_IDS, SimTelemetry

__all__ = ["MavlinkSimVehicle", "DEFAULT_ORIGIN"]

Vec3 = tuple[float, float, float]
#: the scenario's geodetic origin (services/planner/scenarios/monorail.toml): lat, lon (deg), alt (m)
DEFAULT_ORIGIN: Vec3 = (-33.87601, 151.191182, 0.0)
_ON_GROUND = (Mode.IDLE, Mode.LANDED)
#: the flight logic (AUTO's items, a GUIDED leg, the sticks) runs at least this often, simulated s: a pass that
#: comes late (its process starved of CPU at an accelerated clock) catches up in such slices, as the firmware's
#: scheduler runs it every loop
FLIGHT_LOGIC_PERIOD_S = 0.05
_ZERO: Vec3 = (0.0, 0.0, 0.0)


class MavlinkSimVehicle(SimTelemetry, SimCommands):
    """A simulated ArduCopter on a MAVLink connection (pymavlink string: ``udpout:host:port`` to reach a
    listener, ``udpin:host:port`` to be dialled), system id ``uav``, launch point ``home`` (ENU m); the other
    options are those of ``skynet sim-autopilot`` (docs/cli.md; ``firmware`` is its ``--firmware-version``,
    ``param_overrides`` its ``--param``).
    """

    def __init__(self, connection: str, uav: int, home: Vec3 = (0.0, 0.0, 0.0), speed: float = 1.0, *,
                 epoch: float | None = None, params: SimParams = SimParams(), seed: int = 0, telemetry_hz: float = 20.0,
                 refuse_arming: bool = False, origin: Vec3 = DEFAULT_ORIGIN, mavlink_key: str | None = None,
                 param_overrides: dict[str, float] | None = None, boot_scale: float = 0.0, stream_all: bool = False,
                 firmware: str = DEFAULT_SCHEME, legacy_mission_request: bool = False, rc_centred: bool = False):
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
        self.streams = StreamScheduler(STREAM_IDS, rates)
        self.missions = MissionServer(home=self._home_item, legacy_request=legacy_mission_request)
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
        self.rc_centred = bool(rc_centred)
        self._stick_hold: tuple[float, float, float, float, float] | None = None  # x, y, z, t, yaw at entry
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
        with contextlib.suppress(OSError):
            self._conn.close()

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
        self._advance(self.clock.now(), now)
        self._startup_texts()
        for name in self.streams.due(now):
            self._stream(name)

    def _advance(self, until: float, now: float) -> None:
        """The flight logic, the simulation and the rules after a step (landed-disarm, failsafes, fence) on to
        simulated time ``until``, at least every :data:`FLIGHT_LOGIC_PERIOD_S` however late this pass is
        (``now``: its monotonic time); a gap beyond the simulation's bound in one step, which refuses it (a wrong
        clock, not a late pass)."""
        sim = self.sim
        while True:
            self._fly()
            at = until if until - sim.t > MAX_STEP_S else min(until, sim.t + FLIGHT_LOGIC_PERIOD_S)
            try:
                sim.step(at)
            except ValueError as exc:
                self.errors.append(f"step: {exc}")
                at = until
            self._after_step(now)
            if at >= until or sim.t <= at - FLIGHT_LOGIC_PERIOD_S:  # there, or the simulation did not move
                return

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
        """Let AUTO (or a GUIDED reposition, or the absent sticks) choose the simulated vehicle's reference."""
        if self.custom_mode in STICK_MODES and not self.rc_centred:
            self._sticks()
            return
        self._stick_hold = None
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
                self._send(M.MAVLink_mission_item_reached_message(v))
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

    def _sticks(self) -> None:
        """A stick mode with no RC input: the throttle rests at its bottom, so the vehicle descends where it
        is at the pilot's full descent rate (:data:`.apm.modes.PILOT_DESCENT_MS`) and lands, as ArduCopter's
        LOITER does with its throttle stick down; the centred roll and pitch sticks hold the position."""
        sim = self.sim
        if not self.airborne or sim.mode != Mode.HOLD:
            self._stick_hold = None
            return
        st = sim.state()
        if self._stick_hold is None:
            self._stick_hold = (st.pos[0], st.pos[1], st.pos[2], sim.t, st.att[2])
        x, y, z0, t0, yaw = self._stick_hold
        z = z0 - PILOT_DESCENT_MS * (sim.t - t0)
        if z <= self.home[2] + 0.3:  # the ground: touch down (and disarm once landed)
            self._stick_hold = None
            sim.land()
            return
        sim.set_external_reference(GuidedTarget((x, y, z), (0.0, 0.0, -PILOT_DESCENT_MS), _ZERO, yaw, sim.t))

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

    # ------------------------------------------------------------------ input
    def _handle(self, msg: Any) -> None:
        """One received message: HEARTBEAT (the GCS failsafe's), else its handler in :data:`HANDLERS` when
        addressed to this vehicle (target system 0 or ``uav``)."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        self._peer_heard = True
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if kind == "HEARTBEAT":
            if msg.type == M.MAV_TYPE_GCS:
                self.gcs_heartbeats += 1
            if src[0] == int(self.params[self.params.name("gcs_sysid")]):
                self._gcs_mono = time.monotonic()
            return
        handler = HANDLERS.get(kind)
        if handler is not None and getattr(msg, "target_system", None) in (0, self.uav):
            handler(self, msg, src, time.monotonic())

    def _on_command(self, msg: Any, src: tuple[int, int], is_int: bool) -> None:
        result = self._command(_CommandInt(msg) if is_int else msg, is_int)
        self.commands.append((int(msg.command), result))
        self._send(M.MAVLink_command_ack_message(msg.command, result, 0, 0, src[0], src[1]))

    def _on_set_mode(self, msg: Any, src: tuple[int, int]) -> None:
        ok = msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        result = self._set_mode(msg.custom_mode) if ok else M.MAV_RESULT_UNSUPPORTED
        self._send(M.MAVLink_command_ack_message(M.MAVLINK_MSG_ID_SET_MODE, result, 0, 0, src[0], src[1]))

    def _on_mission_count(self, msg: Any, src: tuple[int, int], now: float) -> None:
        if self.boot.booting(self.boot_time()):  # the firmware's mission storage is not up yet
            self._send(M.MAVLink_mission_ack_message(src[0], src[1], M.MAV_MISSION_NO_SPACE, msg.mission_type))
        else:
            self._out(self.missions.count(src, msg.mission_type, msg.count, now))

    def _on_clear(self, msg: Any, src: tuple[int, int]) -> None:
        self._out(self.missions.clear(src, msg.mission_type))
        if msg.mission_type in (MISSION, 255):
            self.auto = None


def _inside(p: Vec3, poly: list[Vec3]) -> bool:
    """Point-in-polygon (even-odd rule) in the horizontal plane."""
    x, y = p[0], p[1]
    inside = False
    for (x1, y1, _), (x2, y2, _) in zip(poly, poly[1:] + poly[:1]):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


#: message type -> handler(vehicle, message, (source system, component), monotonic now)
HANDLERS: dict[str, Callable[[MavlinkSimVehicle, Any, tuple[int, int], float], None]] = {
    "COMMAND_LONG": lambda v, m, src, now: v._on_command(m, src, False),
    "COMMAND_INT": lambda v, m, src, now: v._on_command(m, src, True),
    "SET_MODE": lambda v, m, src, now: v._on_set_mode(m, src),
    "SET_POSITION_TARGET_LOCAL_NED": lambda v, m, src, now: v._position_target(m),
    "PARAM_REQUEST_LIST": lambda v, m, src, now: v._out(v.params.request_list()),
    "PARAM_REQUEST_READ": lambda v, m, src, now: v._out(v.params.request_read(m.param_id, m.param_index, src)),
    "PARAM_SET": lambda v, m, src, now: v._out(v.params.param_set(m.param_id, m.param_value, src)),
    "REQUEST_DATA_STREAM": lambda v, m, src, now: v.streams.request_data_stream(m.req_stream_id, m.req_message_rate,
                                                                                m.start_stop),
    "MISSION_COUNT": lambda v, m, src, now: v._on_mission_count(m, src, now),
    "MISSION_ITEM_INT": lambda v, m, src, now: v._out(v.missions.item(src, item_from_message(m, True), True, now)),
    "MISSION_ITEM": lambda v, m, src, now: v._out(v.missions.item(src, item_from_message(m, False), False, now)),
    "MISSION_REQUEST_LIST": lambda v, m, src, now: v._out(v.missions.request_list(src, m.mission_type)),
    "MISSION_REQUEST_INT": lambda v, m, src, now: v._out(v.missions.request(src, m.mission_type, m.seq, True)),
    "MISSION_REQUEST": lambda v, m, src, now: v._out(v.missions.request(src, m.mission_type, m.seq, False)),
    "MISSION_CLEAR_ALL": lambda v, m, src, now: v._on_clear(m, src),
    "MISSION_SET_CURRENT": lambda v, m, src, now: v._set_current(m.seq),
}
