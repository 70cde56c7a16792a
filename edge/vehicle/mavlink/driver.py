"""The MAVLink driver: an autopilot behind :class:`VehicleDriver` (see the package docstring)."""

from __future__ import annotations

import contextlib
import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Literal

from pymavlink.dialects.v20 import ardupilotmega as M

from edge.geometry.ardupilot_items import capture_params
from edge.geometry.waypoint_mission import geodetic_to_enu
from edge.vehicle.driver import (
    MAX_DEAD_RECKON_S,
    CaptureEvent,
    DriverState,
    VehicleDriver,
    check_vec3,
    shutter_position,
)
from edge.vehicle.sequencer import MissionSequencer
from protocol.messages import AutopilotReadiness, Mode, Trajectory

from .auto import AutoFlight
from .commands import CommandAwaiter, CommandRefused, VehicleLinkError, await_reply
from .dialect import ARDUCOPTER, Dialect, dialect_for
from .guided import Target, TargetStream
from .handlers import Telemetry, dispatch, stream_requests
from .link import Link
from .params import ParamClient
from .phase import GROUNDED, Phase, overrule
from .progress import MissionProgress

__all__ = ["MavlinkParams", "MavlinkDriver", "safe_mode_name"]

log = logging.getLogger("skynet.mavlink")
Vec3 = tuple[float, float, float]

_GROUNDED = (Mode.IDLE, Mode.LANDED)
_AIRBORNE = (Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.LAND, Mode.RTL, Mode.FAILSAFE, Mode.PILOT)


def safe_mode_name(name: object, limit: int = 32) -> str:
    """A mode name fit to publish: letters, digits and ``_ . -`` kept, anything else (control characters, markup,
    non-ASCII) as ``?``, at most ``limit`` characters."""
    text = str(name)[: limit * 4]
    return "".join(c if c.isascii() and (c.isalnum() or c in "_.-") else "?" for c in text)[:limit]


@dataclass(frozen=True)
class MavlinkParams:
    """Tuning of :class:`MavlinkDriver` (defaults as :class:`edge.vehicle.sim.SimParams` where shared), SI
    units and wall seconds; each option's meaning: docs/hardware-mavlink.md, "Driver options"."""

    transit_speed: float = 4.0
    start_radius: float = 1.0
    arrive_radius: float = 0.5
    max_offset: float = 3.0
    offset_rate: float = 1.0
    takeoff_tolerance: float = 0.3
    heartbeat_timeout_s: float = 3.0
    retries: int = 1
    trigger_camera: bool = False
    interpolation: Literal["cubic", "linear"] = "cubic"
    accel_feedforward: bool = True
    appear_timeout_s: float = 10.0
    flight: Literal["guided", "auto"] = "guided"
    auto_speed_gain: float = 0.6
    auto_speed_period_s: float = 0.1
    auto_end_wait_s: float = 5.0
    capture_radius: float = 1.0

    def __post_init__(self) -> None:
        for k in ("transit_speed", "start_radius", "arrive_radius", "offset_rate", "takeoff_tolerance",
                  "heartbeat_timeout_s", "capture_radius"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{k} must be finite and > 0")
        if not (math.isfinite(self.max_offset) and self.max_offset >= 0):
            raise ValueError("max_offset must be finite and >= 0")
        if not (isinstance(self.appear_timeout_s, (int, float)) and 0 <= self.appear_timeout_s <= 600):
            raise ValueError("appear_timeout_s must be in [0, 600] s")
        if not (isinstance(self.retries, int) and 0 <= self.retries <= 10):
            raise ValueError("retries must be an int in 0..10")
        if self.interpolation not in ("cubic", "linear"):
            raise ValueError("interpolation must be 'cubic' or 'linear'")
        if self.flight not in ("guided", "auto"):
            raise ValueError("flight must be 'guided' or 'auto'")
        for k in ("auto_speed_gain", "auto_speed_period_s", "auto_end_wait_s"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 < v <= 10):
                raise ValueError(f"{k} must be in (0, 10]")


#: how far from the mission frame's origin an autopilot's home may be, m (farther: another site's scenario)
MAX_HOME_DISTANCE_M = 20_000.0


def home_in_frame(home_lla: tuple[float, float, float], origin: Vec3,
                  max_distance_m: float = MAX_HOME_DISTANCE_M) -> Vec3:
    """An autopilot's HOME_POSITION (degrees, degrees, m above sea level) in the mission's ENU frame about its
    geodetic ``origin`` (WGS84, :func:`edge.geometry.waypoint_mission.geodetic_to_enu`); ValueError when it is
    not a geodetic point or lies farther than ``max_distance_m`` from the origin."""
    lat, lon, alt = (float(v) for v in home_lla)
    if not (abs(lat) <= 90 and abs(lon) <= 180 and math.isfinite(alt)):
        raise ValueError(f"the autopilot's home {home_lla!r} is not a geodetic point")
    e, n, u = (float(v) for v in geodetic_to_enu((lat, lon, alt), origin))
    if not math.hypot(e, n) <= max_distance_m:
        raise ValueError(f"the autopilot's home ({lat:.6f}, {lon:.6f}) is {math.hypot(e, n) / 1000:.1f} km from the "
                         f"scenario's origin ({origin[0]:.6f}, {origin[1]:.6f}): another site's scenario?")
    return (round(float(e), 3), round(float(n), 3), round(float(u), 3))


class MavlinkDriver(ParamClient, VehicleDriver):
    """An autopilot (ArduCopter's or PX4's dialect) over MAVLink 2 behind the driver interface.

    ``connection`` is a pymavlink connection string (e.g. ``"udpin:0.0.0.0:14550"``), ``home`` the launch
    point in the mission's ENU frame (the autopilot's local NED origin); ``sysid`` None takes the first
    autopilot heard, ``dialect`` None takes it from its HEARTBEAT. ``signing_key``, ``gcs_endpoint`` and
    ``home_origin``: docs/hardware-mavlink.md, "Driver options".
    """

    def __init__(self, uav: int, connection: str, home: Vec3 = (0.0, 0.0, 0.0), rate_hz: float = 20.0,
                 timeout_s: float = 1.5, *, params: MavlinkParams = MavlinkParams(), sysid: int | None = None,
                 source_system: int = 255, source_component: int = M.MAV_COMP_ID_ONBOARD_COMPUTER,
                 signing_key: str | None = None, gcs_endpoint: str | None = None, gcs_video: Any = None,
                 dialect: Dialect | None = None, home_origin: Vec3 | None = None, clock_rate: float = 1.0):
        if not (isinstance(uav, int) and 1 <= uav <= 255):
            raise ValueError("uav must be an int in 1..255")
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 0 < rate_hz <= 100):
            raise ValueError("rate_hz must be in (0, 100]")
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and 0 < timeout_s <= 60):
            raise ValueError("timeout_s must be in (0, 60]")
        if not (isinstance(clock_rate, (int, float)) and math.isfinite(clock_rate) and 0 < clock_rate <= 1000):
            raise ValueError("clock_rate must be in (0, 1000]")
        #: mission seconds per wall second (the board's --speed; the autopilot's clock runs as fast)
        self.clock_rate = float(clock_rate)
        if sysid is not None and not (isinstance(sysid, int) and 1 <= sysid <= 255):
            raise ValueError("sysid must be None or an int in 1..255")
        if not isinstance(params, MavlinkParams):
            raise ValueError("params must be a MavlinkParams")
        self.uav, self.connection, self.params, self._dialect = uav, connection, params, dialect
        self.home = check_vec3(home, "home")
        self._home_origin = None if home_origin is None else check_vec3(home_origin, "home_origin")
        #: the autopilot's home adopted as the launch point (``home_origin``), and why one was not
        self.home_adopted: Vec3 | None = None
        self._home_refused = ""
        self.rate_hz, self.timeout_s = float(rate_hz), float(timeout_s)
        hb_type = M.MAV_TYPE_GCS
        if gcs_endpoint is not None:
            hb_type = M.MAV_TYPE_ONBOARD_CONTROLLER
            if source_system == 255:
                source_system = uav
        self._mono0 = time.monotonic()
        self._closed = False
        self.tel = Telemetry(uav, self.home, source_system, sysid)
        self._lock = self.tel.lock  # telemetry, phase, acks
        self.commands = CommandAwaiter(self.tel, self._send_command, self.timeout_s, params.retries)
        self._cmd_rx = 0  # receive index of the last accepted command's ack
        #: autopilot modes the driver did not command and noticed (the dialect's names, in order)
        self.external_modes: list[str] = []
        self.phase = Phase.IDLE
        self._t = 0.0
        self._takeoff_z = self.home[2]
        self._takeoff_yaw = 0.0
        self._hold: tuple[Vec3, float] = (self.home, 0.0)  # position, ENU yaw
        self._traj: Trajectory | None = None
        #: the trajectory, its start/pause/resume, the formation offset and the captures (under _lock)
        self.mission = MissionSequencer(
            uav, self.home[2], transit_speed=params.transit_speed, start_radius=params.start_radius,
            arrive_radius=params.arrive_radius, max_offset=params.max_offset, offset_rate=params.offset_rate,
            interpolation=params.interpolation)
        self.targets = TargetStream(self.rate_hz, self.home)
        self._priming = False  # a switch to a setpoint-stream guided mode (OFFBOARD) is being prepared
        self._confirming = 0  # mode switches awaiting their HEARTBEAT
        self._switcher = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"mavlink-uav{uav}-mode")
        self._preflight_done = False
        #: the AUTO flight strategy (None when flying GUIDED)
        self.auto = AutoFlight(self) if params.flight == "auto" else None
        self.bridge = None
        self._last_req = -math.inf
        self.link = Link(connection, source_system, source_component, name=f"mavlink-uav{uav}", hb_type=hb_type,
                         on_message=self._on_message, on_tick=self._on_tick, signing_key=signing_key)
        if gcs_endpoint is not None:
            from edge.vehicle.gcs_bridge import GcsBridge

            self.bridge = GcsBridge(gcs_endpoint, self.link.write, video=gcs_video)
        self.link.start()

    # ------------------------------------------------------------------ link
    def _on_message(self, msg: Any, now: float) -> None:
        bridge = self.bridge
        if bridge is not None:
            bridge.to_gcs(msg)
        dispatch(self.tel, msg, now)
        if self._home_origin is not None and self.home_adopted is None and self.tel.home_lla is not None:
            self._adopt_home(self.tel.home_lla)

    def _adopt_home(self, lla: tuple[float, float, float]) -> None:
        """Take the autopilot's HOME_POSITION as the launch point (on the ground, once; later homes, such as
        ArduCopter's reset at arming, are not followed: the local NED origin stays the one flown from)."""
        assert self._home_origin is not None
        try:
            home = home_in_frame(lla, self._home_origin)
        except ValueError as exc:
            if self._home_refused != str(exc):
                log.error("UAV %d: %s", self.uav, exc)
            self._home_refused = str(exc)
            return
        with self._lock:
            if self.phase is not Phase.IDLE:
                return
            old = self.home
            self.home = self.tel.home = self.targets.home = home
            self.tel.pos = tuple(p - o + h for p, o, h in zip(self.tel.pos, old, home))  # type: ignore[assignment]
            self._hold = (home, self._hold[1])
            self._takeoff_z = self.mission.ground_z = home[2]
            self.home_adopted = home
        log.info("UAV %d: home from the autopilot: %.6f, %.6f, %.1f m = (%.2f, %.2f, %.2f) in the mission frame",
                 self.uav, *lla, *home)

    @property
    def dialect(self) -> Dialect:
        """The autopilot family: the one given, else the one its HEARTBEAT names (ArduCopter until heard)."""
        if self._dialect is not None:
            return self._dialect
        return dialect_for(self.tel.autopilot) or ARDUCOPTER

    def _on_tick(self, now: float) -> None:
        if self.tel.hb is not None and now - self._last_req >= 2.0:
            self._last_req = now
            for msg in stream_requests(self.tel, now):
                self.link.send(msg)
        self._keep_stream(now)

    def _keep_stream(self, now: float) -> None:
        """OFFBOARD's setpoint stream (a dialect with ``setpoint_stream``): while the driver streams (hold, mission)
        or prepares a switch, the last target again when the board has not sent one for 0.2 s (PX4 leaves
        OFFBOARD after COM_OF_LOSS_T, 1 s, without one; it needs > 2 Hz), e.g. while a command blocks the board."""
        if not self.dialect.setpoint_stream:
            return
        with self._lock:
            streaming = self._priming or (self.phase in (Phase.HOLD, Phase.MISSION) and not self._closed)
            msg = self.targets.last_msg
            if not streaming or msg is None or now - self.targets.last_mono < 0.2 or not self.link_ok:
                return
            self.targets.last_mono = now
        self.link.send(msg)

    def _send_command(self, command: int, confirmation: int, p: tuple[float, ...], frame: int | None) -> None:
        sysid, compid = self.tel.sysid or 0, self.tel.compid
        if frame is None:
            self.link.send(M.MAVLink_command_long_message(sysid, compid, command, confirmation, *p))
        else:
            self.link.send(M.MAVLink_command_int_message(sysid, compid, frame, command, 0, 0, *p[:4], int(p[4]),
                                                         int(p[5]), p[6]))

    @property
    def link_errors(self) -> int:
        """Undecodable datagrams, malformed values and send errors on the link."""
        return self.link.errors + self.tel.errors

    def mission_progress(self) -> MissionProgress | None:
        """The autopilot's own mission progress in AUTO (MISSION_CURRENT, MISSION_ITEM_REACHED and the
        trajectory fractions they allow; :mod:`.progress`), None in GUIDED flight or before AUTO was entered."""
        with self._lock:
            return self.auto.progress() if self.auto is not None else None

    def readiness(self) -> AutopilotReadiness:
        """The autopilot's readiness to fly: HEARTBEAT heard, its system_status past BOOT, home known
        (HOME_POSITION), an absolute position estimate (EKF_STATUS_REPORT flags, the dialect's
        ``position_ok``), the pre-arm checks passing (SYS_STATUS pre-arm bit healthy), and the
        autopilot's latest "PreArm:", "Arm:" or mode-refusal STATUSTEXT as the reason while not ready; and
        the autopilot's own mode, ``external`` when the edge did not command it (a pilot took over)."""
        tel = self.tel
        with tel.lock:
            hb, home, flags, prearm, text = tel.hb, tel.home_lla, tel.ekf_flags, tel.prearm_ok, tel.not_ready_text
            local = "LOCAL_POSITION_NED" in tel.last_mono
        if self._home_origin is not None and self.home_adopted is None:
            home = None  # not ready before the launch point is the autopilot's
        heard = self.link_ok
        e = M.enums["MAV_STATE"].get(hb.status) if hb is not None else None
        status = e.name.removeprefix("MAV_STATE_").lower() if e is not None else ""
        booting = hb is None or hb.status in (M.MAV_STATE_UNINIT, M.MAV_STATE_BOOT, M.MAV_STATE_CALIBRATING)
        position = self.dialect.position_ok(flags) if flags is not None else (home is not None and local)
        armable = prearm is not False
        ready = heard and not booting and home is not None and position and armable
        why = ""
        if not ready:
            if not heard:
                why = str(self._link_error() or "no HEARTBEAT")
            elif booting:
                why = f"the autopilot is starting (system status {status or 'unknown'})"
            elif home is None:
                why = self._home_refused or "no home position yet"
            elif not position:
                why = "no absolute position estimate yet (EKF not using GPS)"
            else:
                why = "its pre-arm checks fail"
            if text and heard:
                why += f"; the autopilot says: {text}"
        with self._lock:
            external = self.phase is Phase.EXTERNAL
        return AutopilotReadiness(ready=ready, heartbeat=heard, status=status, home=home is not None,
                                  position=position, armable=armable, reason=why[:256],
                                  mode=safe_mode_name(self.dialect.mode_name(hb.custom_mode)) if hb is not None else "",
                                  external=external)

    def heartbeat_age(self) -> float | None:
        """Seconds since the last autopilot HEARTBEAT (None: none yet)."""
        hb = self.tel.hb
        return None if hb is None else time.monotonic() - hb.mono

    @property
    def link_ok(self) -> bool:
        """An autopilot HEARTBEAT arrived within ``heartbeat_timeout_s``."""
        age = self.heartbeat_age()
        return age is not None and age <= self.params.heartbeat_timeout_s

    @property
    def target_system(self) -> int | None:
        """The autopilot's system id (None until heard)."""
        return self.tel.sysid

    def _link_error(self) -> VehicleLinkError | None:
        age = self.heartbeat_age()
        if age is None:
            waited = time.monotonic() - self._mono0
            return VehicleLinkError(f"no HEARTBEAT from an autopilot on {self.connection} in {waited:.1f} s: "
                                    "is the vehicle connected and sending to this endpoint?")
        if age > self.params.heartbeat_timeout_s:
            return VehicleLinkError(f"autopilot link lost: last HEARTBEAT {age:.1f} s ago on {self.connection}")
        if self.tel.autopilot != self.dialect.autopilot:
            e = M.enums["MAV_AUTOPILOT"].get(self.tel.autopilot)
            speaks = self.dialect.name if self._dialect is not None else "ArduCopter's and PX4"
            return VehicleLinkError(f"the autopilot is {e.name if e else self.tel.autopilot}: this driver speaks "
                                    f"{speaks}'s modes only")
        return None

    def wait_heartbeat(self, timeout_s: float = 5.0) -> None:
        """Block until an autopilot HEARTBEAT is heard; :class:`VehicleLinkError` after ``timeout_s``."""
        if not (math.isfinite(timeout_s) and timeout_s >= 0):
            raise ValueError("timeout_s must be finite and >= 0")
        deadline = time.monotonic() + timeout_s
        with self.tel.cv:
            while not self.link_ok:
                left = deadline - time.monotonic()
                if left <= 0:
                    err = self._link_error()
                    assert err is not None
                    raise err
                self.tel.cv.wait(min(left, 0.1))

    def command(self, command: int, params: tuple[float, ...], what: str) -> None:
        """Send a COMMAND_LONG and wait for its COMMAND_ACK (:class:`.commands.CommandRefused` unless accepted)."""
        err = self._link_error()
        if err is not None:
            raise err
        rx = self.commands.call(command, params, what)
        with self._lock:
            self._cmd_rx = max(self._cmd_rx, rx)

    def set_mode(self, mode: int) -> None:
        """DO_SET_MODE; for a setpoint-stream guided mode (PX4's OFFBOARD) the stream runs first; for a dialect
        that acknowledges twice (PX4: ACCEPTED, then the verdict) the mode is confirmed by a HEARTBEAT."""
        d = self.dialect
        what = f"set mode {d.mode_name(mode)}"
        if not d.confirm_mode:
            self.command(M.MAV_CMD_DO_SET_MODE, d.set_mode_params(mode), what)
            return
        err = self._link_error()
        if err is not None:
            raise err
        with self._lock:
            self._confirming += 1  # no HEARTBEAT overrules the phase meanwhile (it may still show the old mode)
        try:
            if d.setpoint_stream and mode == d.guided:
                self._prime_setpoints()
            rx = self.commands.call(M.MAV_CMD_DO_SET_MODE, d.set_mode_params(mode), what)
            hb_rx = self._confirm_mode(mode, rx, what)
            with self._lock:
                self._cmd_rx = max(self._cmd_rx, hb_rx)
        finally:
            with self._lock:
                self._confirming -= 1
                if not self._confirming:
                    self._priming = False

    def _prime_setpoints(self, lead_s: float = 0.5) -> None:
        """Start the setpoint stream ``lead_s`` before a switch to OFFBOARD (PX4 refuses it without > 2 Hz of
        setpoints): the target being streamed, else a hold at the vehicle's position."""
        tel = self.tel
        with self._lock:
            self._priming = True
            if not (self.phase in (Phase.HOLD, Phase.MISSION) and self.targets.last_msg is not None):
                msg = self.targets.message((tel.pos, None, None, tel.att[2]), tel.sysid or 0, tel.compid)
            else:
                msg = self.targets.last_msg
            self.targets.last_mono = time.monotonic()
        self.link.send(msg)
        time.sleep(lead_s)  # the link's tick repeats it (:meth:`_keep_stream`)

    def _confirm_mode(self, mode: int, ack_rx: int, what: str, timeout_s: float = 3.0) -> int:
        """After DO_SET_MODE's first ACCEPTED: the receive index of a HEARTBEAT in ``mode``; CommandRefused when a
        second COMMAND_ACK refuses it, VehicleLinkError when no HEARTBEAT shows it within ``timeout_s``."""
        tel, cmd = self.tel, M.MAV_CMD_DO_SET_MODE
        deadline = time.monotonic() + timeout_s
        with tel.cv:
            while True:
                ack = tel.acks.get(cmd)
                if ack is not None and ack[1] > ack_rx and ack[0] not in (M.MAV_RESULT_ACCEPTED,
                                                                         M.MAV_RESULT_IN_PROGRESS):
                    tel.acks.pop(cmd, None)
                    texts = tuple(t for _, _, t in list(tel.texts)[-3:])
                    raise CommandRefused(what, cmd, ack[0], texts)
                hb = tel.hb
                if hb is not None and hb.rx > ack_rx and hb.custom_mode == int(mode):
                    tel.acks.pop(cmd, None)
                    return hb.rx
                left = deadline - time.monotonic()
                if left <= 0:
                    raise VehicleLinkError(f"{what}: accepted, but no HEARTBEAT in that mode within {timeout_s:g} s")
                tel.cv.wait(min(left, 0.1))

    def _switch_soon(self, mode: int, expect: Phase) -> None:
        """Switch to ``mode`` on the driver's mode thread (``step`` never waits), if still in phase ``expect``."""
        def run() -> None:
            with self._lock:
                if self.phase is not expect or self._closed:
                    return
            try:
                self.set_mode(mode)
            except ValueError as exc:
                log.warning("UAV %d: switch to %s failed: %s", self.uav, self.dialect.mode_name(mode), exc)

        with contextlib.suppress(RuntimeError):  # closed meanwhile
            self._switcher.submit(run)

    def _preflight(self) -> None:
        """The dialect's parameters set once before the first takeoff (PX4: NAV_DLL_ACT = 2, Return on a
        data-link loss, which is off by default); best effort, a warning when refused."""
        if self._preflight_done:
            return
        self._preflight_done = True
        for key, value in self.dialect.preflight_params:
            try:
                self.set_param_si(key, value)
            except ValueError as exc:
                log.warning("UAV %d: could not set %s: %s", self.uav, key, exc)

    def _home_amsl(self, timeout_s: float = 3.0) -> float | None:
        """The autopilot's home altitude above sea level (HOME_POSITION, asked for when not heard yet)."""
        tel = self.tel
        if tel.home_lla is None:
            ask = M.MAVLink_command_long_message(tel.sysid or 0, tel.compid, M.MAV_CMD_REQUEST_MESSAGE, 0,
                                                 M.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0)
            await_reply(tel.cv, lambda _: self.link.send(ask), lambda: tel.home_lla, 1.0, max(0, int(timeout_s) - 1))
        home = tel.home_lla
        return None if home is None else home[2]

    def _ensure_guided(self) -> None:
        """Switch to the guided mode unless the driver already flies in it (and no newer HEARTBEAT disagrees)."""
        guided = self.dialect.guided
        with self._lock:
            hb = self.tel.hb
            fresh = hb is not None and hb.rx > self._cmd_rx
            if self.dialect.confirm_mode:  # its HEARTBEAT shows every mode the driver set: it decides
                fresh = hb is not None
            if self.phase in (Phase.HOLD, Phase.MISSION, Phase.TAKEOFF) and not (fresh and hb.custom_mode != guided):
                return
        self.set_mode(guided)

    # ------------------------------------------------------------------ mode machine (phase.py)
    def _update_phase(self) -> None:
        """Let a HEARTBEAT newer than the last accepted command overrule the driver's phase."""
        hb = self.tel.hb
        if hb is None or hb.rx <= self._cmd_rx or self._confirming:
            return
        pending = self.auto.pending if self.auto is not None else ()
        o = overrule(self.phase, armed=hb.armed, guided=hb.custom_mode == self.dialect.guided,
                     expected=hb.custom_mode in self.dialect.phase_modes(self.phase) or hb.custom_mode in pending)
        if o.noticed:
            name = self.dialect.mode_name(hb.custom_mode)
            self.external_modes.append(name)
            log.warning("UAV %d: the autopilot is in %s, a mode the edge did not command (pilot or failsafe): "
                        "the mission is paused and the edge stops commanding until resumed", self.uav, name)
        if o.pause:
            self.mission.pause(self._t)
        if o.phase is Phase.HOLD and self.phase is not Phase.HOLD:
            self._hold_here()
        self.phase = o.phase

    def _mode(self) -> Mode:
        if not self.link_ok:
            return Mode.FAILSAFE
        mode = self.phase.mode
        if mode is None:
            hb = self.tel.hb
            return self.dialect.board_mode(hb.custom_mode) if hb is not None else Mode.FAILSAFE
        return mode

    def _require(self, allowed: tuple[Mode, ...], what: str) -> Mode:
        if self._closed:
            raise ValueError("driver is closed")
        if self.heartbeat_age() is None and self.params.appear_timeout_s > 0:
            # not heard yet: give the autopilot time to appear instead of a fixed window (a failure is reported below)
            with contextlib.suppress(VehicleLinkError):
                self.wait_heartbeat(self.params.appear_timeout_s)
        err = self._link_error()
        if err is not None:
            raise err
        with self._lock:
            self._update_phase()
            mode = self._mode()
        if mode not in allowed:
            names = ", ".join(m.value for m in allowed)
            raise ValueError(f"cannot {what} in mode {mode.value} (allowed in: {names})")
        return mode

    def _armed(self) -> bool:
        """Armed per the last HEARTBEAT, or per the phase when no HEARTBEAT followed the last command."""
        hb = self.tel.hb
        if hb is not None and hb.rx > self._cmd_rx:
            return hb.armed
        return self.phase not in GROUNDED

    # ------------------------------------------------------------------ state
    def state(self) -> DriverState:
        tel = self.tel
        with self._lock:
            self._update_phase()
            wp, prog = self.mission.progress(self._t)
            if self.auto is not None and self.phase in (Phase.AUTO, Phase.HOLD):  # AUTO: as the autopilot says
                wp, prog = self.auto.follow(wp, prog)
            return DriverState(t=self._t, pos=tel.pos, vel=tel.vel, att=tel.att, rates=tel.rates, mode=self._mode(),
                               armed=self._armed(), battery=tel.battery, wp_index=wp, progress=prog,
                               captures=self.mission.captures)

    # ------------------------------------------------------------------ commands
    def upload(self, traj: Trajectory) -> None:
        if not (self.heartbeat_age() is None and self.phase is Phase.IDLE and not self._closed):
            self._require((Mode.IDLE, Mode.LANDED, Mode.TAKEOFF, Mode.HOLD), "upload a trajectory")
        with self._lock:  # before the autopilot appears: stored here, flown once it is there
            self.mission.load(traj)
            self._traj = traj

    def takeoff(self, altitude: float) -> None:
        self._require(_GROUNDED, "take off")
        altitude = float(altitude)
        if not (math.isfinite(altitude) and 0.5 <= altitude <= 500.0):
            raise ValueError("takeoff altitude must be in [0.5, 500] m")
        d = self.dialect
        self._preflight()
        param7 = d.takeoff_altitude(altitude, self._home_amsl() if not d.home_item else None)
        latlon = (0, 0) if d.home_item else (math.nan, math.nan)  # PX4: NaN = where it is
        self.set_mode(d.arm_mode)
        self.command(M.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "arm")
        try:
            self.command(M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, math.nan, *latlon, param7), f"take off to {altitude:g} m")
        except ValueError:
            with contextlib.suppress(ValueError):  # do not leave the motors armed on the ground
                self.command(M.MAV_CMD_COMPONENT_ARM_DISARM, (0.0,), "disarm")
            raise
        with self._lock:
            self.phase = Phase.TAKEOFF
            self._takeoff_z = self.home[2] + altitude
            self._takeoff_yaw = self.tel.att[2]

    def start(self, t0: float | None = None) -> None:
        self._require((Mode.HOLD,), "start a mission")
        self.mission.check_start(t0)
        if self.auto is not None:
            self.auto.prepare(self._traj)
        self._ensure_guided()
        with self._lock:
            self.mission.start(self._t, self.tel.pos, t0)
            self.phase = Phase.MISSION
            self.targets.restart()

    def hold(self) -> None:
        self._require(_AIRBORNE, "hold")
        if self.phase is Phase.HOLD:
            return
        if not self._armed():
            raise ValueError("cannot hold: the vehicle is not armed")
        self._ensure_guided()
        with self._lock:
            self.mission.pause(self._t)
            self._hold_here()

    def resume(self) -> None:
        self._require((Mode.HOLD, Mode.PILOT), "resume")
        self.mission.check_resume()
        self._ensure_guided()
        with self._lock:
            self.mission.resume(self._t, self.tel.pos, self.tel.att[2])  # flies back keeping its heading
            self.phase = Phase.MISSION
            self.targets.restart()

    def land(self) -> None:
        self._fly_home(Phase.LAND, M.MAV_CMD_NAV_LAND, (0, 0, 0, math.nan, 0, 0, 0), "land")

    def return_to_launch(self) -> None:
        self._fly_home(Phase.RTL, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, (), "return to launch")

    def _fly_home(self, phase: Phase, command: int, params: tuple[float, ...], what: str) -> None:
        """NAV_LAND (the autopilot lands and disarms on the ground) or NAV_RETURN_TO_LAUNCH."""
        self._require(_AIRBORNE, what)
        if self.phase is phase:
            return
        self.command(command, params, what)
        with self._lock:
            self.mission.cancel()
            self.phase = phase

    def set_reference_offset(self, offset: Vec3) -> None:
        if self._closed:
            raise ValueError("driver is closed")
        with self._lock:
            self.mission.set_offset(offset)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._switcher.shutdown(wait=False, cancel_futures=True)
        if self.auto is not None:
            self.auto.close()
        self.link.close()
        if self.bridge is not None:
            self.bridge.close()

    def __enter__(self) -> MavlinkDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ mission bookkeeping (under _lock)
    def _hold_here(self) -> None:
        self.phase = Phase.HOLD
        self._hold = (self.tel.pos, self.tel.att[2])
        self.targets.restart()

    def _shutter(self) -> Vec3:
        """The vehicle's position now: the last valid LOCAL_POSITION_NED carried forward over its age (at 20 Hz and
        the mission's 2 m/s, up to 10 cm behind; docs/hardware-mavlink.md): at most :data:`MAX_DEAD_RECKON_S` of
        wall time, in mission seconds (``clock_rate``)."""
        tel = self.tel
        if tel.pos_mono is None:
            return tel.pos
        age = min(time.monotonic() - tel.pos_mono, MAX_DEAD_RECKON_S)
        return shutter_position(tel.pos, tel.vel, age * self.clock_rate)

    def _mission_reference(self, t: float, dt: float, events: list[CaptureEvent], in_auto: bool = False) -> Target:
        """The mission's target at time t (the sequencer's reference, as this driver streams it).

        Waiting at the first waypoint and holding at the end: position and yaw; transit:
        position, velocity and yaw; tracking: also the acceleration (``accel_feedforward``).
        In AUTO (``in_auto``) the captures are not the clock's (:meth:`.auto.AutoFlight.captures_due`) and the
        trajectory's end does not end the phase (the autopilot's mission does).
        """
        m, tel, auto = self.mission, self.tel, self.auto
        p, v, a, yaw = m.reference(t, tel.pos, dt)
        due = m.due(t)
        if in_auto and auto is not None:
            m.captures -= len(due)  # counted when fired by position or MISSION_ITEM_REACHED instead
            if m.done:
                return p, None, None, yaw
        else:
            if auto is not None:
                auto._fired.update(w.capture_id for w in due)
            if due:
                here = self._shutter()
                events.extend(CaptureEvent(w.capture_id, t, here, tel.att) for w in due)
        if m.done:
            self.phase = Phase.HOLD
            self._hold = (p, yaw)
            return p, None, None, yaw
        if m.phase == "track":
            return p, v, (a if self.params.accel_feedforward else None), yaw
        return p, (None if m.phase == "wait" else v), None, yaw

    # ------------------------------------------------------------------ streaming
    def step(self, until_t: float) -> list[CaptureEvent]:
        """Advance to mission time ``until_t`` (the board's clock, :mod:`edge.clock`): the reference of the
        shared :class:`MissionSequencer`, position targets (GUIDED) or speed corrections (AUTO), and the
        captures due; never waits for the link."""
        if self._closed:
            raise ValueError("driver is closed")
        until_t = float(until_t)
        if not math.isfinite(until_t):
            raise ValueError("until_t must be finite")
        events: list[CaptureEvent] = []
        target: Target | None = None
        speed: Any = None
        auto, tel = self.auto, self.tel
        with self._lock:
            dt = until_t - self._t
            self._t = until_t
            self._update_phase()
            if not self.link_ok:
                return events
            phase = self.phase
            if (phase is Phase.TAKEOFF and tel.pos[2] >= self._takeoff_z - self.params.takeoff_tolerance
                    and abs(tel.vel[2]) < 0.3):
                self.phase = phase = Phase.HOLD
                self._hold = ((tel.pos[0], tel.pos[1], self._takeoff_z), self._takeoff_yaw)
                self.targets.restart()
                if self.dialect.setpoint_stream:  # PX4 holds in AUTO.LOITER: hold in OFFBOARD, ready to start
                    self._switch_soon(self.dialect.guided, Phase.HOLD)
            if phase is Phase.MISSION:
                target = self._mission_reference(until_t, dt, events)
                if auto is not None and self.mission.phase == "track":
                    auto.enter(until_t)
            elif phase is Phase.AUTO and auto is not None:
                ref = None if self.mission.done else self._mission_reference(until_t, dt, events, in_auto=True)
                here = self._shutter()
                fired = auto.captures_due(here)
                self.mission.captures += len(fired)
                events.extend(CaptureEvent(cid, until_t, here, tel.att) for cid in fired)
                if self.mission.done:  # the clock ran out: follow the autopilot's mission to its end, then hold
                    auto.ended()
                    if auto.finished():
                        self._hold_here()
                        phase = Phase.HOLD
                elif ref is not None:
                    speed = auto.speed_message(ref)
            if phase is Phase.HOLD:
                if auto is not None:
                    auto.hold_tick()
                target = (self._hold[0], None, None, self._hold[1])
            if target is not None and not self.targets.due(time.monotonic()):
                target = None  # streamed recently enough
        if target is not None:
            self.link.send(self.targets.message(target, tel.sysid or 0, tel.compid))
        if speed is not None:
            self.link.send(speed)
        if self.params.trigger_camera:
            for ev in events:
                self.link.send(M.MAVLink_command_long_message(tel.sysid or 0, tel.compid,
                                                              M.MAV_CMD_DO_DIGICAM_CONTROL, 0,
                                                              *capture_params(ev.capture_id)))
        return events
