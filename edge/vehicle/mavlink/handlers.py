"""What the driver hears from the autopilot: a table from MAVLink message type to handler.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/handlers.py).
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.angles import wrap_angle
from edge.vehicle.px4.params import decode
from protocol.messages import MAX_COORD_M, MAX_SPEED_MS

__all__ = ["Heartbeat", "Telemetry", "HANDLERS", "dispatch", "stream_requests", "STREAMS", "LEGACY_STREAMS", "ned_to_enu",
           "enu_to_ned", "yaw_ned_to_enu", "yaw_enu_to_ned", "attitude_ned_to_enu", "rates_frd_to_flu"]

log = logging.getLogger("skynet.mavlink")
Vec3 = tuple[float, float, float]

#: telemetry the driver asks for: message name -> (id, rate Hz)
STREAMS = {"LOCAL_POSITION_NED": (M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20.0),
           "ATTITUDE": (M.MAVLINK_MSG_ID_ATTITUDE, 20.0), "SYS_STATUS": (M.MAVLINK_MSG_ID_SYS_STATUS, 2.0),
           "EKF_STATUS_REPORT": (M.MAVLINK_MSG_ID_EKF_STATUS_REPORT, 1.0),
           "HOME_POSITION": (M.MAVLINK_MSG_ID_HOME_POSITION, 0.5),
           "MISSION_CURRENT": (M.MAVLINK_MSG_ID_MISSION_CURRENT, 1.0)}
#: the REQUEST_DATA_STREAM groups (ArduCopter's) holding them: name -> (MAV_DATA_STREAM, rate Hz)
LEGACY_STREAMS = {"LOCAL_POSITION_NED": (M.MAV_DATA_STREAM_POSITION, 20), "ATTITUDE": (M.MAV_DATA_STREAM_EXTRA1, 20),
                  "SYS_STATUS": (M.MAV_DATA_STREAM_EXTENDED_STATUS, 2), "EKF_STATUS_REPORT": (M.MAV_DATA_STREAM_EXTRA3, 1),
                  "MISSION_CURRENT": (M.MAV_DATA_STREAM_EXTENDED_STATUS, 2)}
#: STATUSTEXT prefixes and fragments that say why an autopilot will not fly yet
NOT_READY_TEXTS = ("PreArm:", "Arm:", "requires position", "Need Position")


# ---------------------------------------------------------------------------------- frames
def ned_to_enu(v: Any) -> np.ndarray:
    """NED vector(s) -> ENU: ``(x, y, z)_enu = (y, x, −z)_ned``; shape (..., 3), vectorised.

    Positions get the home offset added by the caller (the NED origin is the launch point).

    >>> ned_to_enu([1.0, 2.0, -3.0]).tolist()
    [2.0, 1.0, 3.0]
    """
    a = np.asarray(v, dtype=float)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError("vector must have 3 components in its last axis")
    if not np.all(np.isfinite(a)):
        raise ValueError("vector must be finite")
    out = a[..., [1, 0, 2]].copy()
    out[..., 2] *= -1.0
    return out


def enu_to_ned(v: Any) -> np.ndarray:
    """ENU vector(s) -> NED (the same swap-and-flip as :func:`ned_to_enu`, its own inverse)."""
    return ned_to_enu(v)


def yaw_ned_to_enu(yaw: float) -> float:
    """Heading from north, clockwise (NED) -> from east, counter-clockwise (ENU): ``π/2 − ψ``, wrapped."""
    if not math.isfinite(yaw):
        raise ValueError("yaw must be finite")
    return wrap_angle(math.pi / 2.0 - yaw)


def yaw_enu_to_ned(yaw: float) -> float:
    """ENU yaw -> NED yaw (the same map: ``π/2 − ψ`` is an involution)."""
    return yaw_ned_to_enu(yaw)


def attitude_ned_to_enu(roll: float, pitch: float, yaw: float) -> Vec3:
    """ZYX Euler angles of an FRD body in NED -> of the FLU body in ENU: ``(φ, −θ, π/2 − ψ)``."""
    if not (math.isfinite(roll) and math.isfinite(pitch)):
        raise ValueError("roll and pitch must be finite")
    return (float(roll), -float(pitch), yaw_ned_to_enu(yaw))


def rates_frd_to_flu(p: float, q: float, r: float) -> Vec3:
    """Body rates about FRD axes -> about FLU axes: ``(p, −q, −r)`` (also the inverse)."""
    return (float(p), -float(q), -float(r))


# ---------------------------------------------------------------------------------- telemetry
@dataclass(frozen=True)
class Heartbeat:
    armed: bool
    custom_mode: int
    rx: int  # receive index (orders heartbeats against command acks)
    mono: float  # time.monotonic() of reception
    status: int = M.MAV_STATE_STANDBY  # system_status


class Telemetry:
    """The autopilot as last heard (every field under ``lock``; ``cv`` is notified on news)."""

    def __init__(self, uav: int, home: Vec3, our_system: int, sysid: int | None = None):
        self.uav, self.home, self.our_system = uav, home, our_system
        self.lock = threading.RLock()
        self.cv = threading.Condition(self.lock)
        self.sysid = sysid
        self.compid = M.MAV_COMP_ID_AUTOPILOT1
        self.compid_locked = False
        #: the autopilot's MAV_AUTOPILOT (from its HEARTBEAT; None until heard)
        self.autopilot: int | None = None
        self.rx = 0  # receive index of heartbeats, acks and parameter answers
        self.hb: Heartbeat | None = None
        self.pos: Vec3 = home
        self.vel: Vec3 = (0.0, 0.0, 0.0)
        self.pos_mono: float | None = None  # time.monotonic() of the report pos and vel are from (a valid one)
        self.att: Vec3 = (0.0, 0.0, 0.0)
        self.rates: Vec3 = (0.0, 0.0, 0.0)
        self.battery = 1.0
        self.last_mono: dict[str, float] = {}
        self.texts: deque[tuple[float, int, str]] = deque(maxlen=16)
        self.not_ready_text = ""
        self.acks: dict[int, tuple[int, int]] = {}  # command -> (result, rx)
        self.ekf_flags: int | None = None
        self.prearm_ok: bool | None = None
        self.legacy_streams = False
        self.home_lla: tuple[float, float, float] | None = None
        self.mission_rx: deque[Any] = deque(maxlen=64)
        self.reached_seq = -1  # the autopilot's latest MISSION_ITEM_REACHED
        self.current_seq = -1  # the autopilot's current mission item (MISSION_CURRENT)
        self.mission_total = -1  # MISSION_CURRENT's ``total`` (the autopilot's item count; −1 before one)
        self.mission_count = -1  # items the driver uploaded (−1: none): progress beyond them is refused
        self.progress_rejected = 0  # MISSION_CURRENT / MISSION_ITEM_REACHED ignored (see :func:`_mission_current`)
        self.param_rx: dict[str, tuple[float, int]] = {}  # name -> (value, rx)
        self.param_err: dict[str, int] = {}  # name -> rx of its PARAM_ERROR
        self.errors = 0  # undecodable datagrams and malformed values

    def next_rx(self) -> int:
        self.rx += 1
        self.cv.notify_all()
        return self.rx


def _param_id(raw: Any) -> str:
    """A PARAM_VALUE / PARAM_ERROR ``param_id`` (char[16], not NUL-terminated at 16) as text."""
    if isinstance(raw, (bytes, bytearray)):
        raw = bytes(raw).split(b"\0", 1)[0].decode("ascii", "replace")
    return str(raw).split("\0", 1)[0].strip()[:16]


def _heartbeat(t: Telemetry, msg: Any, now: float) -> None:
    if msg.autopilot == M.MAV_AUTOPILOT_INVALID:
        return  # a GCS or another companion, not a vehicle
    src, comp = msg.get_srcSystem(), msg.get_srcComponent()
    if t.sysid is None:
        t.sysid = src
    if src != t.sysid:
        return
    if not t.compid_locked:  # the first autopilot component heard (not a gimbal or camera)
        t.compid, t.compid_locked, t.autopilot = comp, True, int(msg.autopilot)
    if comp != t.compid:
        return
    t.hb = Heartbeat(bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED), int(msg.custom_mode), t.next_rx(), now,
                     int(msg.system_status))
    t.last_mono["HEARTBEAT"] = now


def _local_position(t: Telemetry, msg: Any, now: float) -> None:
    p = ned_to_enu((msg.x, msg.y, msg.z)) + t.home
    v = ned_to_enu((msg.vx, msg.vy, msg.vz))
    if np.any(np.abs(p) > MAX_COORD_M) or np.any(np.abs(v) > MAX_SPEED_MS):  # the wire contract's sane bounds
        raise ValueError("position or velocity beyond any flight")
    t.pos, t.vel = (float(p[0]), float(p[1]), float(p[2])), (float(v[0]), float(v[1]), float(v[2]))
    t.pos_mono = now


def _attitude(t: Telemetry, msg: Any, now: float) -> None:
    t.att = attitude_ned_to_enu(msg.roll, msg.pitch, msg.yaw)
    t.rates = rates_frd_to_flu(msg.rollspeed, msg.pitchspeed, msg.yawspeed)


def _sys_status(t: Telemetry, msg: Any, now: float) -> None:
    if 0 <= msg.battery_remaining <= 100:
        t.battery = msg.battery_remaining / 100.0
    bit = M.MAV_SYS_STATUS_PREARM_CHECK
    if msg.onboard_control_sensors_present & bit and msg.onboard_control_sensors_enabled & bit:
        t.prearm_ok = bool(msg.onboard_control_sensors_health & bit)


def _statustext(t: Telemetry, msg: Any, now: float) -> None:
    text = msg.text.decode(errors="replace") if isinstance(msg.text, bytes) else str(msg.text)
    text = text.rstrip("\x00")
    t.texts.append((now, int(msg.severity), text))
    if any(k in text for k in NOT_READY_TEXTS):
        t.not_ready_text = text[:200]


def _home_position(t: Telemetry, msg: Any, now: float) -> None:
    lla = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1e3)
    if abs(lla[0]) <= 90 and abs(lla[1]) <= 180:
        t.home_lla = lla
        t.cv.notify_all()


def _param_value(t: Telemetry, msg: Any, now: float) -> None:
    name = _param_id(msg.param_id)
    value = float(msg.param_value)
    if t.autopilot == M.MAV_AUTOPILOT_PX4:  # PX4 sends an integer parameter's bytes in the float field
        value = decode(value, int(msg.param_type))
    if name and math.isfinite(value) and len(t.param_rx) < 4096:
        t.param_rx[name] = (value, t.next_rx())
    elif name:
        t.errors += 1


def _param_error(t: Telemetry, msg: Any, now: float) -> None:
    name = _param_id(msg.param_id)
    if msg.target_system == t.our_system and name and len(t.param_err) < 4096:
        t.param_err[name] = t.next_rx()


def _mission(t: Telemetry, msg: Any, now: float) -> None:
    if msg.target_system == t.our_system:
        t.mission_rx.append(msg)
        t.cv.notify_all()


def _mission_current(t: Telemetry, msg: Any, now: float) -> None:
    """MISSION_CURRENT: the item the autopilot flies to. Ignored (counted in ``progress_rejected``) when outside the
    uploaded mission, or before an item it already reported reached (progress never moves back)."""
    seq, total = int(msg.seq), int(getattr(msg, "total", 0) or 0)
    if 0 <= total < 65535:
        t.mission_total = total
    n = t.mission_count
    if seq < 0 or (n >= 0 and seq >= n) or seq < t.reached_seq:
        t.progress_rejected += 1
        return
    t.current_seq = seq
    t.cv.notify_all()


def _mission_item_reached(t: Telemetry, msg: Any, now: float) -> None:
    """MISSION_ITEM_REACHED: ignored (counted) outside the uploaded mission or beyond the item after the current
    one (an autopilot reaches the item it flies to: a report far ahead would jump the edge's progress); a
    repeat (PX4 repeats it about once a second) or an older item changes nothing."""
    seq, n = int(msg.seq), t.mission_count
    if seq < 0 or (n >= 0 and seq >= n) or seq > t.current_seq + 1:
        t.progress_rejected += 1
        return
    if seq > t.reached_seq:
        t.reached_seq = seq
        t.current_seq = max(t.current_seq, seq)
        t.cv.notify_all()


def _command_ack(t: Telemetry, msg: Any, now: float) -> None:
    if (msg.command == M.MAV_CMD_SET_MESSAGE_INTERVAL and not t.legacy_streams
            and msg.result in (M.MAV_RESULT_UNSUPPORTED, M.MAV_RESULT_FAILED)):
        t.legacy_streams = True
        log.info("UAV %d: the autopilot refused SET_MESSAGE_INTERVAL: asking with REQUEST_DATA_STREAM", t.uav)
    t.acks[int(msg.command)] = (int(msg.result), t.next_rx())


HANDLERS: dict[str, Callable[[Telemetry, Any, float], None]] = {
    "HEARTBEAT": _heartbeat, "LOCAL_POSITION_NED": _local_position, "ATTITUDE": _attitude,
    "SYS_STATUS": _sys_status, "STATUSTEXT": _statustext, "HOME_POSITION": _home_position,
    "EKF_STATUS_REPORT": lambda t, m, now: setattr(t, "ekf_flags", int(m.flags)),
    "MISSION_ITEM_REACHED": _mission_item_reached, "PARAM_VALUE": _param_value, "MISSION_CURRENT": _mission_current,
    "PARAM_ERROR": _param_error, "MISSION_REQUEST_INT": _mission, "MISSION_REQUEST": _mission,
    "MISSION_ACK": _mission, "COMMAND_ACK": _command_ack,
}


def dispatch(t: Telemetry, msg: Any, now: float) -> None:
    """Hand ``msg`` to its handler (a HEARTBEAT from anyone; the rest only from the target system)."""
    kind = msg.get_type()
    if kind == "BAD_DATA":
        t.errors += 1
        return
    with t.cv:
        if kind != "HEARTBEAT":
            if msg.get_srcSystem() != t.sysid:
                return
            t.last_mono[kind] = now
        handler = HANDLERS.get(kind)
        if handler is None:
            return
        try:
            handler(t, msg, now)
        except ValueError:  # a non-finite position or attitude, or one beyond any flight
            t.errors += 1


def stream_requests(t: Telemetry, now: float) -> list[Any]:
    """The requests (fire and forget) for every telemetry message not heard lately: SET_MESSAGE_INTERVAL,
    or REQUEST_DATA_STREAM for its group once the autopilot refused SET_MESSAGE_INTERVAL."""
    out: list[Any] = []
    groups: set[tuple[int, int]] = set()
    with t.lock:
        sysid, compid, legacy, last = t.sysid or 0, t.compid, t.legacy_streams, dict(t.last_mono)
    for name, (msg_id, hz) in STREAMS.items():
        if now - last.get(name, -math.inf) <= max(1.0, 2.5 / hz):
            continue
        if not legacy:
            out.append(M.MAVLink_command_long_message(sysid, compid, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id,
                                                      1e6 / hz, 0, 0, 0, 0, 0))
        elif name in LEGACY_STREAMS:
            groups.add(LEGACY_STREAMS[name])
        elif name == "HOME_POSITION":
            out.append(M.MAVLink_command_long_message(sysid, compid, M.MAV_CMD_GET_HOME_POSITION, 0, 0, 0, 0, 0, 0,
                                                      0, 0))
    out += [M.MAVLink_request_data_stream_message(sysid, compid, g, hz, 1) for g, hz in sorted(groups)]
    return out
