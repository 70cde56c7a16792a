"""The sim autopilot presenting itself as PX4 (``skynet sim-autopilot --firmware px4``).

Message by message: docs/hardware-mavlink.md, "The sim autopilot as PX4".
"""

from __future__ import annotations

import collections
import math
import time
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.apm.boot import BootTimeline
from edge.vehicle.apm.missions import MISSION
from edge.vehicle.apm.modes import CopterMode
from edge.vehicle.apm.streams import DEFAULT_RATES, StreamScheduler
from edge.vehicle.px4 import modes as PX
from edge.vehicle.px4.params import Px4ParamTable
from protocol.messages import Mode

from .telemetry import STREAM_IDS
from .vehicle import MavlinkSimVehicle

__all__ = ["Px4SimVehicle", "PX4_BOOT", "PX4_FLIGHT_SW_VERSION"]

#: PX4's SITL start-up (first HEARTBEAT / BOOT, home, armable, position modes), s
PX4_BOOT = dict(boot_s=1.3, origin_s=2.3, armable_s=4.0, position_s=4.0)
#: PX4 v1.16.0, FIRMWARE_VERSION_TYPE_OFFICIAL
PX4_FLIGHT_SW_VERSION = (1 << 24) | (16 << 16) | (0 << 8) | 255
_ACCEPTED, _DENIED, _FAILED, _TEMP = (M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_DENIED, M.MAV_RESULT_FAILED,
                                      M.MAV_RESULT_TEMPORARILY_REJECTED)
_ARMABLE = frozenset({PX.LOITER, PX.TAKEOFF, PX.MISSION, PX.OFFBOARD})
#: COM_OBL_RC_ACT -> the mode the offboard loss switches to without RC
_OFFBOARD_LOSS = {3: PX.RTL, 4: PX.LAND}
#: NAV_DLL_ACT -> the mode a data-link loss switches to
_LINK_LOSS = {1: PX.LOITER, 2: PX.RTL, 3: PX.LAND}
_MISSION_SEQ_IN = ("MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_INT", "MISSION_REQUEST")


class Px4SimVehicle(MavlinkSimVehicle):
    """A simulated multicopter speaking PX4's MAVLink (see the module docstring); arguments as
    :class:`.vehicle.MavlinkSimVehicle` (``firmware``, ``stream_all`` and ``legacy_mission_request`` do not
    apply; ``param_overrides`` take PX4's names)."""

    def __init__(self, connection: str, uav: int, *args: Any, param_overrides: dict[str, float] | None = None,
                 boot_scale: float = 0.0, remote: tuple[str, int] | None = None, **kw: Any):
        kw.pop("firmware", None)
        kw.pop("stream_all", None)
        super().__init__(connection, uav, *args, boot_scale=boot_scale, **kw)
        self.boot = BootTimeline(scale=boot_scale, **PX4_BOOT)
        self.params: Px4ParamTable = Px4ParamTable(**{"MAV_SYS_ID": uav, **(param_overrides or {})})
        self.flight_sw_version = PX4_FLIGHT_SW_VERSION
        rates = {k: v for k, v in DEFAULT_RATES.items() if k != "EKF_STATUS_REPORT"}
        self.streams = StreamScheduler(STREAM_IDS, rates)
        self._px4_mode = PX.LOITER
        self.modes_flown: list[int] = [PX.LOITER]  # every PX4 mode entered, in order
        self.custom_mode = CopterMode.GUIDED
        self._setpoints: collections.deque[float] = collections.deque(maxlen=8)  # monotonic receive times
        self._mode_verdicts: list[tuple[int, tuple[int, int]]] = []  # DO_SET_MODE to decide at the next poll
        self._takeoff_alt = self.params["MIS_TAKEOFF_ALT"]
        self._landed_mono: float | None = None
        self._took_off = False
        self._reached: tuple[int, float] | None = None  # (wire seq, monotonic) of the last MISSION_ITEM_REACHED
        self._dl_mono: float | None = None  # last GCS HEARTBEAT
        self.link_lost = False
        self.offboard_losses = 0
        #: PX4's GCS link: on a listening (udpin) connection, send to ``remote`` (PX4: 14550) until a ground
        #: station's packet arrives, then to that station
        self.remote = remote
        if remote is not None:
            conn = self._conn
            if not getattr(conn, "udp_server", False):
                raise ValueError("a remote address needs a listening udpin connection")
            conn.clients.add(remote)
            conn.clients_last_alive[remote] = float("inf")

    # ------------------------------------------------------------------ modes
    @property
    def px4_mode(self) -> int:
        """The PX4 custom mode the vehicle is in."""
        return self._px4_mode

    @px4_mode.setter
    def px4_mode(self, custom: int) -> None:
        if custom != self._px4_mode:
            self.modes_flown.append(int(custom))
        self._px4_mode = int(custom)

    def offboard_signal(self, now: float | None = None) -> bool:
        """Setpoints faster than 2 Hz: at least two in the last second, the latest within half a second."""
        now = time.monotonic() if now is None else now
        recent = [t for t in self._setpoints if now - t <= 1.0]
        return len(recent) >= 2 and now - recent[-1] <= 0.5

    def _px4_switch(self, custom: int, takeoff_alt: float | None = None) -> tuple[int, str]:
        """Switch to PX4 mode ``custom``: (MAV_RESULT, refusal reason). AUTO.TAKEOFF climbs to ``takeoff_alt``
        above home (MIS_TAKEOFF_ALT when None) once armed."""
        items = len(self.missions.mission())
        ok, why = PX.check_mode_change(custom, rc=False, offboard_signal=self.offboard_signal(),
                                       mission_items=max(0, items - 1), home=self.home_known, armed=self.armed,
                                       airborne=self.airborne)
        if not ok:
            return _TEMP, why
        if custom == self.px4_mode:
            return _ACCEPTED, ""
        internal = {PX.MISSION: CopterMode.AUTO, PX.RTL: CopterMode.RTL, PX.LAND: CopterMode.LAND}.get(
            custom, CopterMode.GUIDED)
        if internal != self.custom_mode or internal == CopterMode.GUIDED:
            r = MavlinkSimVehicle._set_mode(self, internal)
            if r != _ACCEPTED:
                return _TEMP, f"{PX.mode_name(custom)} not available"
        if custom == PX.LOITER and self.airborne:
            self._hold_here()
            self._leg = None
        if custom == PX.TAKEOFF:
            self._takeoff_alt = self.params["MIS_TAKEOFF_ALT"] if takeoff_alt is None else takeoff_alt
            if self.armed and not self.airborne:
                self.sim.takeoff(max(0.5, self._takeoff_alt))
        self.px4_mode = custom
        return _ACCEPTED, ""

    def _set_px4_mode(self, custom: int) -> int:
        """A mode change the vehicle makes itself (failsafe, end of takeoff): applied and shown at once."""
        r, why = self._px4_switch(custom)
        if r != _ACCEPTED:
            self.errors.append(f"mode change to {PX.mode_name(custom)} refused: {why}")
        self.send_heartbeat()
        return r

    def pilot_mode(self, mode: int) -> None:
        """As the pilot's remote control would (a PX4 custom mode; thread-safe, applied at the next poll)."""
        self._pilot.put(int(mode))

    def poll(self) -> None:
        while not self._pilot.empty():
            r, why = self._px4_switch(self._pilot.get())
            if r != _ACCEPTED:
                self.errors.append(f"pilot mode change refused: {why}")
            self.send_heartbeat()
        if self.remote is not None and len(self._conn.clients) > 1 and self.remote in self._conn.clients:
            self._conn.clients.discard(self.remote)  # a ground station answered: talk to it from now on
        verdicts, self._mode_verdicts = self._mode_verdicts, []
        for custom, src in verdicts:  # PX4's second acknowledgement: the commander's verdict
            r, why = self._px4_switch(custom)
            if r != _ACCEPTED:
                self._text(M.MAV_SEVERITY_CRITICAL, why[:50])
            self._send(M.MAVLink_command_ack_message(M.MAV_CMD_DO_SET_MODE, r, 0, 0, src[0], src[1]))
            self.send_heartbeat()
        super().poll()

    def _set_mode(self, mode: float) -> int:
        """An internal (ArduCopter-numbered) mode change keeps the PX4 mode in step."""
        r = super()._set_mode(mode)
        if r == _ACCEPTED:
            self.px4_mode = {CopterMode.AUTO: PX.MISSION, CopterMode.RTL: PX.RTL, CopterMode.LAND: PX.LAND}.get(
                int(mode), self.px4_mode if self.px4_mode in (PX.OFFBOARD, PX.TAKEOFF) else PX.LOITER)
        return r

    # ------------------------------------------------------------------ input
    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._peer_heard = True
            if msg.type == M.MAV_TYPE_GCS:
                self.gcs_heartbeats += 1
                self._dl_mono = time.monotonic()
            return
        if kind == "PARAM_SET" and msg.target_system in (0, self.uav):  # decoded by its declared type
            src = (msg.get_srcSystem(), msg.get_srcComponent())
            self._out(self.params.param_set(msg.param_id, msg.param_value, src, int(msg.param_type)))
            return
        if kind in _MISSION_SEQ_IN and getattr(msg, "mission_type", 0) == MISSION:
            msg.seq = int(msg.seq) + 1  # PX4's item k is the core's k + 1 (its item 0 is home)
        elif kind == "MISSION_SET_CURRENT":
            msg.seq = int(msg.seq) + 1
        super()._handle(msg)

    def _on_mission_count(self, msg: Any, src: tuple[int, int], now: float) -> None:
        if self.boot.booting(self.boot_time()) or msg.mission_type != MISSION or msg.count <= 0:
            super()._on_mission_count(msg, src, now)
            return
        if msg.count > 10_000:  # the core refuses it (its count, one more, is still out of range)
            super()._on_mission_count(msg, src, now)
            return
        self.missions.count(src, MISSION, int(msg.count) + 1, now)  # asks for the core's item 0: home
        self._out(self.missions.item(src, self._home_item(), True, now))  # answered here; then PX4's item 0

    def _on_command(self, msg: Any, src: tuple[int, int], is_int: bool) -> None:
        if msg.command != M.MAV_CMD_DO_SET_MODE:
            super()._on_command(msg, src, is_int)
            return
        custom = PX.from_set_mode(msg.param2, msg.param3) if math.isfinite(msg.param1) and int(msg.param1) & 1 else None
        if custom is None:
            self.commands.append((int(msg.command), _DENIED))
            self._send(M.MAVLink_command_ack_message(msg.command, _DENIED, 0, 0, src[0], src[1]))
            return
        self.commands.append((int(msg.command), _ACCEPTED))
        self._send(M.MAVLink_command_ack_message(msg.command, _ACCEPTED, 0, 0, src[0], src[1]))
        self._mode_verdicts.append((custom, src))

    def _on_set_mode(self, msg: Any, src: tuple[int, int]) -> None:
        ok = msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        r = self._px4_switch(int(msg.custom_mode))[0] if ok else M.MAV_RESULT_UNSUPPORTED
        self._send(M.MAVLink_command_ack_message(M.MAVLINK_MSG_ID_SET_MODE, r, 0, 0, src[0], src[1]))
        self.send_heartbeat()

    def _command(self, msg: Any, is_int: bool) -> int:
        c = msg.command
        if c == M.MAV_CMD_NAV_TAKEOFF:
            return self._px4_takeoff(msg.param7)
        if c == M.MAV_CMD_NAV_LAND:
            return self._px4_switch(PX.LAND)[0]
        if c == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._px4_switch(PX.RTL)[0]
        if c in (M.MAV_CMD_DO_SET_MISSION_CURRENT, M.MAV_CMD_MISSION_START):
            first = msg.param1
            if c == M.MAV_CMD_MISSION_START:
                r = self._px4_switch(PX.MISSION)[0]
                if r == _ACCEPTED and math.isfinite(first) and first >= 0:
                    self._set_current(first + 1)
                return r
            return _ACCEPTED if math.isfinite(first) and self._set_current(first + 1) else _DENIED
        return super()._command(msg, is_int)

    def _px4_takeoff(self, amsl: float) -> int:
        if self.airborne:
            self._text(M.MAV_SEVERITY_WARNING, "Takeoff denied: already flying")
            return _DENIED
        rel = amsl - self.home_lla[2] if math.isfinite(amsl) else self.params["MIS_TAKEOFF_ALT"]
        if not (0.5 <= rel <= 500.0):
            self._text(M.MAV_SEVERITY_WARNING, "Takeoff denied: altitude out of range")
            return _DENIED
        if self.px4_mode == PX.TAKEOFF:
            self._px4_switch(PX.LOITER)  # a new takeoff altitude: enter AUTO.TAKEOFF again
        r, why = self._px4_switch(PX.TAKEOFF, rel)
        if r != _ACCEPTED:
            self._text(M.MAV_SEVERITY_CRITICAL, why[:50])
            return r
        self.send_heartbeat()
        return _ACCEPTED

    def _arm(self, arm: bool, force: bool) -> int:
        if not arm or self.armed:
            return super()._arm(arm, force)
        if self.refuse_arming:
            self._text(M.MAV_SEVERITY_CRITICAL, "Arming denied: refused by the simulator")
            return _FAILED
        if not self.boot.armable(self.boot_time()):
            self._text(M.MAV_SEVERITY_CRITICAL, "Arming denied: system not ready")
            return _TEMP
        if self.px4_mode not in _ARMABLE or (self.px4_mode == PX.OFFBOARD and not self.offboard_signal()):
            self._text(M.MAV_SEVERITY_CRITICAL, f"Arming denied: not in {PX.mode_name(self.px4_mode)}")
            return _DENIED
        self.armed, self._armed_at, self._took_off = True, self.sim.t, False
        if self.px4_mode == PX.TAKEOFF:
            self.sim.takeoff(max(0.5, self._takeoff_alt))
        return _ACCEPTED

    def _position_target(self, msg: Any) -> None:
        if msg.coordinate_frame != M.MAV_FRAME_LOCAL_NED:
            return
        self._setpoints.append(time.monotonic())  # the offboard signal, whatever the mode (values checked below)
        if self.px4_mode != PX.OFFBOARD:
            return
        if self.armed and not self.airborne and not msg.type_mask & 4 and math.isfinite(msg.z) and -msg.z > 0.5:
            self.sim.takeoff(-float(msg.z))  # a setpoint above the ground lifts off in OFFBOARD
        super()._position_target(msg)

    # ------------------------------------------------------------------ after each step: PX4's own rules
    def _after_step(self, now: float) -> None:
        sim, airborne = self.sim, self.airborne
        if airborne:
            self._took_off, self._landed_mono = True, None
        if self.armed and self._was_airborne and not airborne:
            self._landed_mono = now
        if self.armed and not airborne:
            land_t, pre_t = self.params["COM_DISARM_LAND"], self.params["COM_DISARM_PRFLT"]
            if self._landed_mono is not None and land_t >= 0 and now - self._landed_mono >= land_t:
                self.armed, self._landed_mono = False, None
            elif not self._took_off and sim.mode in (Mode.IDLE, Mode.LANDED) and pre_t > 0 \
                    and sim.t - self._armed_at > pre_t:
                self.armed = False
                self._text(M.MAV_SEVERITY_INFO, "Disarmed by auto preflight disarming")
        self._was_airborne = airborne
        if self.px4_mode == PX.TAKEOFF and airborne and sim.mode == Mode.HOLD:
            self._set_px4_mode(PX.LOITER)  # the takeoff climb finished: Hold
        if self.px4_mode == PX.OFFBOARD and self.armed and self._setpoints \
                and now - self._setpoints[-1] > self.params["COM_OF_LOSS_T"]:
            self.offboard_losses += 1
            self._text(M.MAV_SEVERITY_CRITICAL, "Failsafe: no offboard setpoints")
            self._set_px4_mode(_OFFBOARD_LOSS.get(int(self.params["COM_OBL_RC_ACT"]), PX.LOITER))
        self._link_loss(now)
        if self._reached is not None and self.px4_mode == PX.MISSION and now - self._reached[1] >= 1.0:
            self._reached = (self._reached[0], now)  # PX4 repeats the last item reached about once a second
            super()._send(M.MAVLink_mission_item_reached_message(self._reached[0]))

    def _link_loss(self, now: float) -> None:
        action = int(self.params["NAV_DLL_ACT"])
        if self._dl_mono is None or action == 0 or not (self.armed and self.airborne):
            return
        lost = now - self._dl_mono > self.params["COM_DL_LOSS_T"]
        if lost and not self.link_lost:
            self.link_lost = True
            self._text(M.MAV_SEVERITY_CRITICAL, "Failsafe: no connection to ground control station")
            mode = _LINK_LOSS.get(action)
            if mode is not None:
                self._set_px4_mode(mode)
        elif not lost:
            self.link_lost = False

    def _failsafe_gcs(self, now: float) -> None:  # ArduCopter's: not PX4's
        return

    def _fence(self) -> None:  # ArduCopter's FENCE_*: not simulated for PX4
        return

    # ------------------------------------------------------------------ output
    def _send(self, msg: Any) -> None:
        """Every message out, in PX4's mission numbering (no home item)."""
        kind = msg.get_type()
        if getattr(msg, "mission_type", MISSION) == MISSION:
            if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ITEM_INT", "MISSION_ITEM"):
                msg.seq = int(msg.seq) - 1
            elif kind == "MISSION_COUNT":
                msg.count = max(0, int(msg.count) - 1)
        if kind == "MISSION_ITEM_REACHED":
            msg.seq = int(msg.seq) - 1
            self._reached = (int(msg.seq), time.monotonic())
        super()._send(msg)

    def _stream(self, name: str) -> bool:
        if name == "MISSION_CURRENT":
            n = max(0, len(self.missions.stores[MISSION]) - 1)
            a = self.auto
            seq = max(0, (a.current if a is not None else 1) - 1)
            state = (M.MISSION_STATE_NO_MISSION if n == 0 else M.MISSION_STATE_COMPLETE if a is not None and a.done
                     else M.MISSION_STATE_ACTIVE if self.px4_mode == PX.MISSION
                     else M.MISSION_STATE_NOT_STARTED if a is None else M.MISSION_STATE_PAUSED)
            super()._send(M.MAVLink_mission_current_message(min(seq, max(0, n - 1)), n if n else 65535, state,
                                                            1 if self.px4_mode == PX.MISSION else 0))
            return True
        if name == "SYS_STATUS":
            present = M.MAV_SYS_STATUS_PREARM_CHECK | _SENSORS
            armable = not self.refuse_arming and self.boot.armable(self.boot_time())
            health = _SENSORS | (M.MAV_SYS_STATUS_PREARM_CHECK if armable else 0)
            st = self.sim.state()
            pct = int(round(100 * min(1.0, max(0.0, st.battery))))
            super()._send(M.MAVLink_sys_status_message(present, present, health, 100, self._voltage_mv(st), 150, pct,
                                                       0, 0, 0, 0, 0, 0))
            return True
        if name == "EKF_STATUS_REPORT":
            return False
        return super()._stream(name)

    def send_heartbeat(self) -> None:
        booting = self.boot.booting(self.boot_time())
        status = (M.MAV_STATE_BOOT if booting else M.MAV_STATE_CRITICAL if self.link_lost
                  else M.MAV_STATE_ACTIVE if self.armed else M.MAV_STATE_STANDBY)
        super()._send(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4,
                                                  PX.base_mode(self.px4_mode, armed=self.armed), int(self.px4_mode),
                                                  status, 3))

    def _startup_texts(self) -> None:  # ArduPilot's EKF texts: PX4 says nothing comparable unasked
        return


_SENSORS = (M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL | M.MAV_SYS_STATUS_SENSOR_3D_MAG
            | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | M.MAV_SYS_STATUS_SENSOR_GPS | M.MAV_SYS_STATUS_AHRS
            | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | M.MAV_SYS_STATUS_SENSOR_BATTERY)
