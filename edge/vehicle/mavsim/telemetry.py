"""What the sim autopilot sends: telemetry by name, HEARTBEAT, STATUSTEXT, camera feedback, start-up texts."""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.angles import wrap_angle
from edge.vehicle.apm.missions import MISSION
from edge.vehicle.apm.modes import CopterMode, base_mode
from protocol.messages import Mode

if TYPE_CHECKING:
    from .vehicle import MavlinkSimVehicle

__all__ = ["SimTelemetry", "STREAM_IDS", "FLIGHT_SW_VERSION"]

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
#: the telemetry set (message name -> id) of :mod:`edge.vehicle.apm.streams`
STREAM_IDS = {n: getattr(M, f"MAVLINK_MSG_ID_{n}") for n in (
    "HEARTBEAT", "SYS_STATUS", "GPS_RAW_INT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "VFR_HUD",
    "BATTERY_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION", "MISSION_CURRENT", "EKF_STATUS_REPORT")}
#: the messages the pure cores answer with (:mod:`edge.vehicle.apm.params`, :mod:`edge.vehicle.apm.missions`)
_CORE_MESSAGES = {"param_value": M.MAVLink_param_value_message, "param_error": M.MAVLink_param_error_message,
                  "mission_ack": M.MAVLink_mission_ack_message, "mission_count": M.MAVLink_mission_count_message,
                  "mission_request": M.MAVLink_mission_request_message,
                  "mission_request_int": M.MAVLink_mission_request_int_message,
                  "mission_item": M.MAVLink_mission_item_message, "mission_item_int": M.MAVLink_mission_item_int_message}
#: ArduPilot repeats failing pre-arm checks as STATUSTEXT this often while disarmed, s
PREARM_REPORT_S = 30.0


class SimTelemetry:
    """The sending half of :class:`.vehicle.MavlinkSimVehicle` (a mixin: it uses the vehicle's state)."""

    custom_mode: int  # ArduCopter's flight mode number
    _boot_seen: float  # boot time up to which the start-up STATUSTEXTs were sent
    _prearm_sent: float  # when the failing pre-arm check was last sent

    def _startup_texts(self: MavlinkSimVehicle) -> None:
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

    def _shot(self, capture_id: int, st: Any) -> None:
        self.shots.append(capture_id)
        lat, lon, h = self.enu_to_lla(st.pos)
        r = st.att
        self._send(M.MAVLink_camera_feedback_message(int(time.time() * 1e6), 0, 0, len(self.shots) - 1,
                   round(lat * 1e7), round(lon * 1e7), h, st.pos[2] - self.home[2], math.degrees(r[0]),
                   -math.degrees(r[1]), math.degrees(wrap_angle(math.pi / 2 - r[2])) % 360.0, 0.0, 1, len(self.shots)))

    def _send(self, msg: Any) -> None:
        try:
            self._conn.mav.send(msg)
        except Exception as exc:  # OSError, struct.error, a value out of its field's range
            self.errors.append(f"send {msg.get_type()}: {exc}")

    def _out(self, outs: list[tuple[str, dict]]) -> None:
        """Send the pure cores' answers (:mod:`edge.vehicle.apm`: message name and fields)."""
        for name, fields in outs:
            self._send(_CORE_MESSAGES[name](**fields))

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
            self._send(M.MAVLink_autopilot_version_message(CAPABILITIES, self.flight_sw_version, 0, 0, 0, [0] * 8, [0] * 8,
                       [0] * 8, 0x1209, 0x5740, self.uav))
            return True
        if name not in STREAM_IDS:
            return False
        st = self.sim.state()
        ms = int(max(0.0, self.clock.now() - self._t_boot) * 1000) & 0xFFFFFFFF  # time since boot
        p, v = st.pos, st.vel
        home = self.home_known
        if name in ("LOCAL_POSITION_NED", "HOME_POSITION") and not home:
            return True  # no EKF origin yet: ArduPilot sends neither
        if name == "EKF_STATUS_REPORT":
            flags = self.boot.ekf_flags(self.boot_time())
            var = 0.02 if flags & 16 else 0.5
            self._send(M.MAVLink_ekf_status_report_message(flags, var, var, 0.02, 0.02, 0.0, 0.0))
        elif name == "LOCAL_POSITION_NED":
            self._send(M.MAVLink_local_position_ned_message(ms, p[1] - h[1], p[0] - h[0], -(p[2] - h[2]), v[1], v[0], -v[2]))
        elif name == "ATTITUDE":
            r, q = st.att, st.rates
            self._send(M.MAVLink_attitude_message(ms, r[0], -r[1], wrap_angle(math.pi / 2 - r[2]), q[0], -q[1], -q[2]))
        elif name == "SYS_STATUS":
            present = _SENSORS | M.MAV_SYS_STATUS_GEOFENCE | M.MAV_SYS_STATUS_PREARM_CHECK
            enabled = _SENSORS | M.MAV_SYS_STATUS_PREARM_CHECK | (
                M.MAV_SYS_STATUS_GEOFENCE if self.params["FENCE_ENABLE"] else 0)
            armable = not self.refuse_arming and self.boot.prearm_failure(self.boot_time()) is None
            health = _SENSORS | (0 if self.fence_breached else M.MAV_SYS_STATUS_GEOFENCE) | (
                M.MAV_SYS_STATUS_PREARM_CHECK if armable else 0)
            pct = int(round(100 * min(1.0, max(0.0, st.battery))))
            self._send(M.MAVLink_sys_status_message(present, enabled, health, 100, self._voltage_mv(st), 150, pct,
                       0, 0, 0, 0, 0, 0))
        elif name in ("GLOBAL_POSITION_INT", "GPS_RAW_INT", "VFR_HUD"):
            lat, lon, alt = self.enu_to_lla(p)
            hdg = math.degrees(wrap_angle(math.pi / 2 - st.att[2])) % 360.0
            gs = math.hypot(v[0], v[1])
            if not home:  # ArduPilot sends the (unset, zero) location before the EKF has an origin
                lat = lon = alt = 0.0
            if name == "GLOBAL_POSITION_INT":
                self._send(M.MAVLink_global_position_int_message(ms, round(lat * 1e7), round(lon * 1e7), round(alt * 1000),
                           round((p[2] - h[2]) * 1000), round(v[1] * 100), round(v[0] * 100), round(-v[2] * 100),
                           round(hdg * 100) % 36000))
            elif name == "GPS_RAW_INT":
                cog = round(math.degrees(math.atan2(v[0], v[1])) % 360.0 * 100) % 36000 if gs > 0.2 else 65535
                self._send(M.MAVLink_gps_raw_int_message(int(time.time() * 1e6), M.GPS_FIX_TYPE_3D_FIX, round(lat * 1e7),
                           round(lon * 1e7), round(alt * 1000), 80, 120, round(gs * 100), cog, 12))
            else:
                self._send(M.MAVLink_vfr_hud_message(gs, gs, round(hdg) % 360, 50 if self.airborne else 0, alt, v[2]))
        elif name == "BATTERY_STATUS":
            cells = [self._voltage_mv(st) // 4] * 4 + [65535] * 6
            self._send(M.MAVLink_battery_status_message(0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 32767, cells,
                       150, -1, -1, int(round(100 * min(1.0, max(0.0, st.battery))))))
        elif name == "EXTENDED_SYS_STATE":
            self._send(M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_UNDEFINED, self._landed_state()))
        elif name == "HOME_POSITION":
            lat, lon, alt = self.home_lla
            self._send(M.MAVLink_home_position_message(round(lat * 1e7), round(lon * 1e7), round(alt * 1000), 0.0, 0.0, 0.0,
                       [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0))
        elif name == "MISSION_CURRENT":
            n = len(self.missions.stores[MISSION])
            a = self.auto
            seq = a.current if a is not None else 0
            state = (M.MISSION_STATE_NO_MISSION if n <= 1 else M.MISSION_STATE_COMPLETE if a is not None and a.done
                     else M.MISSION_STATE_ACTIVE if self.custom_mode == CopterMode.AUTO
                     else M.MISSION_STATE_NOT_STARTED if a is None else M.MISSION_STATE_PAUSED)
            self._send(M.MAVLink_mission_current_message(min(seq, max(0, n - 1)) if n else 0, n, state,
                       1 if self.custom_mode == CopterMode.AUTO else 0))
        return True

    @staticmethod
    def _voltage_mv(st: Any) -> int:
        return int(15000 + 1800 * min(1.0, max(0.0, st.battery)))

    def send_heartbeat(self) -> None:
        flying = self.airborne
        base = base_mode(self.custom_mode, armed=self.armed, flying=flying)
        status = (M.MAV_STATE_CRITICAL if self.gcs_failsafe else M.MAV_STATE_BOOT if self.boot.booting(self.boot_time())
                  else M.MAV_STATE_ACTIVE if flying else M.MAV_STATE_STANDBY)
        self._send(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                   int(self.custom_mode), status, 3))

    def _text(self, severity: int, text: str) -> None:
        """A STATUSTEXT, sent (as by the firmware) only once the link has carried a packet from a peer."""
        self.statustexts.append(text)
        if self._peer_heard:
            self._send(M.MAVLink_statustext_message(severity, text.encode()[:50]))
