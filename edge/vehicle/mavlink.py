"""MAVLink vehicle driver: an ArduCopter-style autopilot behind :class:`VehicleDriver`.

The edge's board talks to a real autopilot (or an autopilot simulator, e.g.
:mod:`edge.vehicle.mavsim`) exactly as it talks to the built-in :class:`SimDriver`: this module
maps the driver interface onto MAVLink 2 (pymavlink ``mavutil``, dialect ``ardupilotmega``).
In the paper the Pixhawk does the low-level control (PAPER.md Section 5: the built-in PID
position loop) and the companion computer the high-level control; this driver is the
companion side: it streams the trajectory reference of (P9) (plus the formation correction of
(P8)) as position targets and fires the capture points.

Frames
------
MAVLink's local frame is NED (x north, y east, z down) about the EKF origin, and its body frame
FRD; ours is ENU about the mission origin with a FLU body. With the launch point ``home`` (ENU
m, where the autopilot's EKF origin is)::

    x_enu = y_ned + home_x,   y_enu = x_ned + home_y,   z_enu = −z_ned + home_z
    φ_enu = φ_ned,   θ_enu = −θ_ned,   ψ_enu = π/2 − ψ_ned  (wrapped to (−π, π])
    (p, q, r)_flu = (p, −q, −r)_frd

(the world change is the reflection that swaps x and y and flips z, the body change a half
turn about x; e.g. the ROS REP 103 / MAVROS ``ftf`` conversions). The same formulas are their
own inverses, :func:`enu_to_ned` and :func:`yaw_enu_to_ned` apply them the other way.

Link
----
A reader thread keeps the latest HEARTBEAT (armed flag, ArduCopter custom mode),
LOCAL_POSITION_NED, ATTITUDE, SYS_STATUS (``battery_remaining``), STATUSTEXT and COMMAND_ACK;
it sends our own HEARTBEAT at 1 Hz as a GCS (system 255 by default, so that ArduPilot's GCS
failsafe watches this link) and asks for every message it uses, since ArduPilot sends only
HEARTBEAT until asked: MAV_CMD_SET_MESSAGE_INTERVAL for each (:data:`STREAMS`: 20 Hz position and
attitude, 2 Hz SYS_STATUS, 1 Hz EKF_STATUS_REPORT, 0.5 Hz HOME_POSITION), again every 2 s while
one is missing; an autopilot that answers it UNSUPPORTED or FAILED gets the legacy
REQUEST_DATA_STREAM for the groups holding them instead (:data:`LEGACY_STREAMS`).

Readiness (:meth:`MavlinkDriver.readiness`, in the edge's state): HEARTBEAT heard, its
system_status past BOOT, home known (HOME_POSITION), an absolute position estimate
(EKF_STATUS_REPORT flags as ArduCopter's ``position_ok()``, :func:`.apm.boot.position_ok`), the
pre-arm checks passing (SYS_STATUS pre-arm bit healthy), and the autopilot's latest "PreArm:",
"Arm:" or mode-refusal STATUSTEXT as the reason while it is not ready. The first autopilot
heard (a HEARTBEAT whose ``autopilot`` is not MAV_AUTOPILOT_INVALID) becomes the target, unless
``sysid`` names one. Without a HEARTBEAT for ``heartbeat_timeout_s`` (3 s, the usual GCS "link
lost" time) the state's mode is FAILSAFE and every command raises :class:`VehicleLinkError`
(a ValueError: the board turns it into a rejected acknowledgement with the reason).

Commands
--------
Every COMMAND_LONG waits for its COMMAND_ACK (``timeout_s`` per attempt, ``retries`` resends
with the ``confirmation`` field incremented, MAV_RESULT_IN_PROGRESS keeps waiting); any result
but MAV_RESULT_ACCEPTED raises ValueError naming the MAV_RESULT (and the autopilot's latest
STATUSTEXT, e.g. a PreArm failure).

==================  ===============================================================
driver call         MAVLink
==================  ===============================================================
takeoff(alt)        DO_SET_MODE GUIDED, COMPONENT_ARM_DISARM(1), NAV_TAKEOFF(param7 = alt)
start(t0)           DO_SET_MODE GUIDED if not in it; then SET_POSITION_TARGET_LOCAL_NED stream
                    (flight "auto": mission upload first, AUTO from the start time, below)
hold()              DO_SET_MODE GUIDED if not in it; position target at the current position
resume()            as start, from the paused trajectory time
land()              NAV_LAND (ArduCopter switches to LAND and disarms on the ground)
return_to_launch()  NAV_RETURN_TO_LAUNCH (RTL mode)
capture             optionally DO_DIGICAM_CONTROL(param5 = 1 shoot, param6 = the capture id, apm.items)
==================  ===============================================================

Parameters (:mod:`.apm.params`): :meth:`MavlinkDriver.read_param` / :meth:`~MavlinkDriver.set_param`
speak the parameter protocol (PARAM_REQUEST_READ / PARAM_SET, answered by PARAM_VALUE or
PARAM_ERROR). ArduCopter 4.7 renamed the parameters the project uses and moved them to SI units;
:meth:`~MavlinkDriver.learn_param_scheme` reads 4.7's WP_SPD and falls back on 4.6's
WPNAV_SPEED on PARAM_ERROR (or silence), and :meth:`~MavlinkDriver.set_param_si` /
:meth:`~MavlinkDriver.read_param_si` use the learnt name and unit, else the other scheme's
(WPNAV_SPEED cm/s or WP_SPD m/s, RTL_ALT cm or RTL_ALT_M m, LAND_SPEED cm/s or LAND_SPD_MS m/s).
In AUTO flight the plan's first leg speed becomes the waypoint speed (ArduCopter starts and
re-enters AUTO at it).

Hold is a position target in GUIDED rather than LOITER/BRAKE: it keeps the vehicle in the
mode the driver streams in, so resume needs no mode change, and ArduCopter holds the last
position target if the companion stops talking.

Position targets (``coordinate_frame = MAV_FRAME_LOCAL_NED``) are streamed from :meth:`step`:
``rate_hz`` per wall second on average, or once per call if the caller steps more slowly, with ``type_mask`` (POSITION_TARGET_TYPEMASK bits set
= ignored)::

    TYPE_MASK_POS_VEL_ACC_YAW = YAW_RATE                   = 2048  (trajectory: p, v, a, ψ)
    TYPE_MASK_POS_VEL_YAW     = AX|AY|AZ|YAW_RATE          = 2496  (same, accel_feedforward=False)
    TYPE_MASK_POS_YAW         = VX|VY|VZ|AX|AY|AZ|YAW_RATE = 2552  (hold, waiting: p, ψ)

The trajectory stream carries the follower's velocity and, by default, its acceleration as
feed-forward (ArduCopter 4.1+ integrates the target between messages with them); with position
and velocity only, the position loop lags the reference in the turns (on the test trajectory
through :mod:`edge.vehicle.mavsim` at speed x2: 0.48 m max / 0.20 m RMS tracking error without,
0.17 m / 0.05 m with the acceleration; the simulated vehicle alone, 0.11 m max).

Modes (protocol.messages.Mode)
------------------------------
ArduCopter reports only its custom mode (0 STABILIZE, 3 AUTO, 4 GUIDED, 5 LOITER, 6 RTL,
9 LAND, 17 BRAKE, ...). The driver keeps what it asked for (its *phase*) and reports it while the
autopilot agrees: TAKEOFF / HOLD / MISSION in GUIDED, LAND in LAND, RTL in RTL; disarmed is IDLE
before the first flight and LANDED after. A HEARTBEAT received after the last accepted command
that disagrees (the pilot's remote control or the autopilot's own failsafe took over, as the
paper allows in an emergency) wins, and the mode follows :func:`copter_mode`: AUTO -> MISSION,
GUIDED / LOITER / BRAKE -> HOLD, RTL / SMART_RTL -> RTL, LAND -> LAND, any other (pilot-flown)
mode -> FAILSAFE; the driver then stops streaming until a command takes the vehicle back.

Time
----
``step(until_t)`` receives the board's mission clock (:mod:`edge.clock`); trajectory times,
the transit to the first waypoint and the capture points run on that clock, exactly as with
the simulated vehicle: both drivers take the mission's reference from the same
:class:`edge.vehicle.sequencer.MissionSequencer` (start, transit, wait, track, pause/resume,
formation offset, captures). :meth:`step` never waits for the link; only commands do.

Flight in AUTO (``MavlinkParams(flight="auto")``, ``skynet edge --flight auto``)
--------------------------------------------------------------------------------
The paper's way (:mod:`edge.vehicle.auto_flight`): ``start`` asks for HOME_POSITION, uploads the
trajectory as a waypoint mission with the MAVLink mission protocol (MISSION_COUNT,
MISSION_REQUEST_INT -> MISSION_ITEM_INT, MISSION_ACK; speed items per leg, capture triggers,
no final RTL), then flies to the first waypoint and waits for the start time in GUIDED as
above. When tracking begins it sends DO_SET_MISSION_CURRENT (the item after the last waypoint
passed) and DO_SET_MODE AUTO from a helper thread (:meth:`step` never waits), streaming GUIDED
targets until AUTO is acknowledged. In AUTO it streams no targets: it keeps the sequencer's
reference (trajectory plus the board's formation correction of (P8)) and sends DO_CHANGE_SPEED
(at most every ``auto_speed_period_s``) so that the along-track error goes to zero; captures fire
on the trajectory clock as in GUIDED (the autopilot also fires its own DO_DIGICAM_CONTROL items).
At the trajectory's end it switches back to GUIDED and holds, once the autopilot reports the last
waypoint reached (MISSION_ITEM_REACHED; at most ``auto_end_wait_s`` later). The mission keeps
only the waypoints ArduCopter can fly at the planned speed (:func:`.auto_flight.decimate`). hold / land / RTL / resume work
as in GUIDED (hold and resume go through GUIDED; resume flies back to the paused point and
re-enters AUTO from the right item). While a mode switch is in flight, HEARTBEATs in either the
old or the new mode are expected; any other mode is the pilot's (``external_modes``, logged) and
the driver stops commanding until resumed.

Only ArduCopter's custom-mode numbering is implemented; a PX4 autopilot (whose custom mode packs
main and sub modes, and which needs OFFBOARD instead of GUIDED) is not.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from edge.vehicle.angles import wrap_angle
from edge.vehicle.apm import items as AI
from edge.vehicle.apm.boot import position_ok
from edge.vehicle.apm.items import capture_params
from edge.vehicle.apm.modes import CopterMode
from edge.vehicle.apm.params import SCHEMES, from_raw, param_name, param_type, to_raw
from edge.vehicle.apm.signing import SafeSigningMAVLink, enable_signing, parse_key
from edge.vehicle.driver import CaptureEvent, DriverState, VehicleDriver, check_vec3
from edge.vehicle.sequencer import MissionSequencer
from protocol.messages import AutopilotReadiness, Mode, Trajectory

try:  # pymavlink is the optional "mavlink" extra
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2
except ImportError as _exc:  # pragma: no cover - depends on the installation
    raise ImportError("the MAVLink driver needs pymavlink (pip install 'skynet-inspect[mavlink]')") from _exc

__all__ = [
    "CopterMode",
    "MavlinkParams",
    "MavlinkDriver",
    "VehicleLinkError",
    "TYPE_MASK_POS_VEL_YAW",
    "TYPE_MASK_POS_VEL_ACC_YAW",
    "TYPE_MASK_POS_YAW",
    "copter_mode",
    "copter_mode_name",
    "ned_to_enu",
    "enu_to_ned",
    "yaw_ned_to_enu",
    "yaw_enu_to_ned",
    "attitude_ned_to_enu",
    "rates_frd_to_flu",
    "open_connection",
    "result_name",
    "command_name",
]

log = logging.getLogger("skynet.mavlink")
Vec3 = tuple[float, float, float]
_Target = tuple[Vec3, "Vec3 | None", "Vec3 | None", float]  # ENU position, velocity, acceleration, yaw
M = mavlink2


_COPTER_TO_MODE = {
    CopterMode.AUTO: Mode.MISSION,
    CopterMode.GUIDED: Mode.HOLD,
    CopterMode.LOITER: Mode.HOLD,
    CopterMode.BRAKE: Mode.HOLD,
    CopterMode.RTL: Mode.RTL,
    CopterMode.SMART_RTL: Mode.RTL,
    CopterMode.LAND: Mode.LAND,
}

_IGNORE_ACC = (M.POSITION_TARGET_TYPEMASK_AX_IGNORE | M.POSITION_TARGET_TYPEMASK_AY_IGNORE
               | M.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
_IGNORE_VEL = (M.POSITION_TARGET_TYPEMASK_VX_IGNORE | M.POSITION_TARGET_TYPEMASK_VY_IGNORE
               | M.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
#: SET_POSITION_TARGET_LOCAL_NED type_mask: position, velocity feed-forward and yaw (2496)
TYPE_MASK_POS_VEL_YAW = _IGNORE_ACC | M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
#: SET_POSITION_TARGET_LOCAL_NED type_mask: position, velocity and acceleration feed-forward, yaw (2048)
TYPE_MASK_POS_VEL_ACC_YAW = M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
#: SET_POSITION_TARGET_LOCAL_NED type_mask: position and yaw only (2552)
TYPE_MASK_POS_YAW = TYPE_MASK_POS_VEL_YAW | _IGNORE_VEL

#: telemetry the driver asks for: message name -> (id, rate Hz)
STREAMS = {"LOCAL_POSITION_NED": (M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20.0),
           "ATTITUDE": (M.MAVLINK_MSG_ID_ATTITUDE, 20.0), "SYS_STATUS": (M.MAVLINK_MSG_ID_SYS_STATUS, 2.0),
           "EKF_STATUS_REPORT": (M.MAVLINK_MSG_ID_EKF_STATUS_REPORT, 1.0),
           "HOME_POSITION": (M.MAVLINK_MSG_ID_HOME_POSITION, 0.5)}
#: the REQUEST_DATA_STREAM groups (ArduCopter's) holding them: name -> (MAV_DATA_STREAM, rate Hz)
LEGACY_STREAMS = {"LOCAL_POSITION_NED": (M.MAV_DATA_STREAM_POSITION, 20), "ATTITUDE": (M.MAV_DATA_STREAM_EXTRA1, 20),
                  "SYS_STATUS": (M.MAV_DATA_STREAM_EXTENDED_STATUS, 2), "EKF_STATUS_REPORT": (M.MAV_DATA_STREAM_EXTRA3, 1)}
#: STATUSTEXT prefixes and fragments that say why an autopilot will not fly yet
_NOT_READY_TEXTS = ("PreArm:", "Arm:", "requires position", "Need Position")

_GROUNDED = (Mode.IDLE, Mode.LANDED)
_AIRBORNE = (Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.LAND, Mode.RTL, Mode.FAILSAFE)
#: the autopilot mode each driver phase expects
_PHASE_COPTER = {"takeoff": CopterMode.GUIDED, "hold": CopterMode.GUIDED, "mission": CopterMode.GUIDED,
                 "land": CopterMode.LAND, "rtl": CopterMode.RTL, "auto": CopterMode.AUTO}
_PHASE_MODE = {"idle": Mode.IDLE, "landed": Mode.LANDED, "takeoff": Mode.TAKEOFF, "hold": Mode.HOLD,
               "mission": Mode.MISSION, "land": Mode.LAND, "rtl": Mode.RTL, "auto": Mode.MISSION}


class VehicleLinkError(ValueError):
    """No (recent) HEARTBEAT from the autopilot, or no COMMAND_ACK: the vehicle cannot be commanded."""


def _param_id(raw: Any) -> str:
    """A PARAM_VALUE / PARAM_ERROR ``param_id`` (char[16], not NUL-terminated at 16) as text."""
    if isinstance(raw, (bytes, bytearray)):
        raw = bytes(raw).split(b"\0", 1)[0].decode("ascii", "replace")
    return str(raw).split("\0", 1)[0].strip()[:16]


# ---------------------------------------------------------------------------------- conversions
def _vec3_array(v: Any, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have 3 components in its last axis")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return a


def ned_to_enu(v: Any) -> np.ndarray:
    """NED vector(s) -> ENU: ``(x, y, z)_enu = (y, x, −z)_ned``; shape (..., 3), vectorised.

    Positions get the home offset added by the caller (the NED origin is the launch point).

    Examples
    --------
    >>> ned_to_enu([1.0, 2.0, -3.0]).tolist()
    [2.0, 1.0, 3.0]
    """
    a = _vec3_array(v, "vector")
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


def copter_mode(custom_mode: int) -> Mode:
    """The board's mode for an ArduCopter custom mode flown by someone else (pilot, failsafe).

    AUTO -> MISSION; GUIDED, LOITER, BRAKE -> HOLD; RTL, SMART_RTL -> RTL; LAND -> LAND; every
    other mode (STABILIZE, ALT_HOLD, POSHOLD, ...: a pilot on the sticks) -> FAILSAFE.
    """
    return _COPTER_TO_MODE.get(custom_mode, Mode.FAILSAFE)


def copter_mode_name(custom_mode: int) -> str:
    """ArduCopter's name of a custom mode (``MODE_<n>`` when unknown)."""
    return mavutil.mode_mapping_acm.get(int(custom_mode), f"MODE_{int(custom_mode)}")


def result_name(result: int) -> str:
    """``MAV_RESULT_*`` name of a COMMAND_ACK result."""
    e = M.enums["MAV_RESULT"].get(int(result))
    return e.name if e is not None else f"MAV_RESULT {int(result)}"


def command_name(command: int) -> str:
    """``MAV_CMD_*`` name of a command id (or ``MAVLINK_MSG_ID_<n>`` for a message acked as a command)."""
    e = M.enums["MAV_CMD"].get(int(command))
    return e.name if e is not None else f"MAVLINK_MSG_ID_{int(command)}"


class _Clients(set):
    """pymavlink's ``udpin:`` peer set, iterated over a snapshot.

    ``mavudp.write`` sends to every address that has sent to it, iterating this set, while the reader
    thread's ``recv`` adds each new sender: a datagram from a new address (anyone on the network) arriving
    during a send raised ``RuntimeError: Set changed size during iteration`` out of the driver's command
    (seen in CI: a forged packet from another port during a takeoff). Every change pymavlink makes (add,
    discard, remove, ``-=``) and the snapshot take one lock (a snapshot copied without it still raised once:
    the copy is not atomic under the GIL).
    """

    def __init__(self, *args) -> None:
        super().__init__(*args)
        self._lock = threading.Lock()

    def add(self, item) -> None:
        with self._lock:
            set.add(self, item)

    def discard(self, item) -> None:
        with self._lock:
            set.discard(self, item)

    def remove(self, item) -> None:
        with self._lock:
            set.remove(self, item)

    def __isub__(self, other):
        with self._lock:
            set.difference_update(self, other)
        return self

    def __iter__(self):
        with self._lock:
            snapshot = set.copy(self)
        return iter(snapshot)


def open_connection(connection: str, source_system: int, source_component: int) -> Any:
    """A pymavlink connection (``udpin:``, ``udpout:``, ``tcp:``, serial, ...) speaking MAVLink 2.

    The connection's encoder is replaced by the MAVLink 2 ``ardupilotmega`` one, so the wire
    version does not depend on the ``MAVLINK20`` environment variable at import time.
    """
    if not isinstance(connection, str) or not connection.strip():
        raise ValueError("connection must be a pymavlink connection string, e.g. 'udpin:0.0.0.0:14550'")
    for v, name in ((source_system, "source_system"), (source_component, "source_component")):
        if not (isinstance(v, int) and 0 <= v <= 255):
            raise ValueError(f"{name} must be an int in 0..255")
    try:
        conn = mavutil.mavlink_connection(connection, source_system=source_system,
                                          source_component=source_component)
    except Exception as exc:  # pymavlink raises OSError, ValueError, serial errors, ...
        raise ValueError(f"cannot open MAVLink connection {connection!r}: {exc}") from exc
    conn.mav = SafeSigningMAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    conn.mav.robust_parsing = True
    if isinstance(getattr(conn, "clients", None), set):
        conn.clients = _Clients(conn.clients)
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    return conn


# ---------------------------------------------------------------------------------- the driver
@dataclass(frozen=True)
class MavlinkParams:
    """Tuning of :class:`MavlinkDriver` (defaults as :class:`edge.vehicle.sim.SimParams` where shared).

    Attributes
    ----------
    transit_speed : speed of the reference flying to the first waypoint / back to a paused point, m/s.
    start_radius : ``start`` flies to the first waypoint first when farther than this, m.
    arrive_radius : a transit counts as arrived when the vehicle is this close to its end, m.
    max_offset : bound on the formation offset's norm, m.
    offset_rate : the applied offset moves toward the commanded one at most this fast, m/s.
    takeoff_tolerance : takeoff is complete within this height of the target, m.
    heartbeat_timeout_s : link lost after this long without an autopilot HEARTBEAT, s.
    retries : COMMAND_LONG resends when no COMMAND_ACK arrives.
    trigger_camera : send MAV_CMD_DO_DIGICAM_CONTROL at each capture (not waiting for the ack).
    interpolation : trajectory interpolation, "cubic" or "linear".
    accel_feedforward : also send the trajectory's acceleration (ArduCopter >= 4.1 uses it);
        False sends position, velocity and yaw only (older firmware).
    appear_timeout_s : a command given before the autopilot's first HEARTBEAT waits this long for
        it to appear (an autopilot still booting, a link still coming up) before failing; 0 fails
        at once. A trajectory upload before then is stored without waiting.
    flight : "guided" streams the reference as position targets; "auto" uploads the trajectory as
        a waypoint mission and flies it in AUTO, kept in time by DO_CHANGE_SPEED
        (:mod:`edge.vehicle.auto_flight`).
    auto_speed_gain : along-track error to ground-speed gain in AUTO, 1/s.
    auto_speed_period_s : at most one DO_CHANGE_SPEED per this many wall seconds (unless the
        speed changes by more than 0.5 m/s).
    auto_end_wait_s : when the trajectory's clock runs out in AUTO, the switch to GUIDED waits for
        the autopilot to reach the mission's last waypoint (MISSION_ITEM_REACHED) at most this
        long, wall s, so that its last capture items run.
    """

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

    def __post_init__(self) -> None:
        for k in ("transit_speed", "start_radius", "arrive_radius", "offset_rate", "takeoff_tolerance",
                  "heartbeat_timeout_s"):
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


@dataclass(frozen=True)
class _Heartbeat:
    armed: bool
    custom_mode: int
    rx: int  # receive index (orders heartbeats against command acks)
    mono: float  # time.monotonic() of reception
    status: int = M.MAV_STATE_STANDBY  # system_status


class MavlinkDriver(VehicleDriver):
    """An ArduCopter-style autopilot over MAVLink 2 behind the driver interface.

    Parameters
    ----------
    uav : int
        UAV id (trajectories for another id are refused).
    connection : str
        pymavlink connection string, e.g. ``"udpin:0.0.0.0:14550"`` (listen for the autopilot).
    home : (x, y, z)
        Launch point in the mission's ENU frame, m: where the autopilot's local NED origin is.
    rate_hz : float
        Position-target stream rate (at most this many per wall second), Hz.
    timeout_s : float
        How long a command waits for its COMMAND_ACK per attempt, s.
    params : MavlinkParams
    sysid : int or None
        The autopilot's MAVLink system id; None takes the first autopilot heard.
    source_system, source_component : int
        Our own MAVLink address (255 / MAV_COMP_ID_ONBOARD_COMPUTER by default: a GCS-side id).
    signing_key : str or None
        MAVLink 2 signing key (64 hex digits or a passphrase, :mod:`edge.vehicle.apm.signing`):
        every packet out is signed and only correctly signed packets are accepted, the signature
        checked before the stream's timestamp is recorded. None: unsigned.
    gcs_endpoint : str or None
        A MAVLink endpoint for the operator's ground station (:mod:`edge.vehicle.gcs_bridge`): the
        autopilot's traffic is forwarded there and the GCS's to the autopilot. With it the driver
        speaks as the companion computer (system id ``uav`` unless ``source_system`` is given,
        HEARTBEAT type MAV_TYPE_ONBOARD_CONTROLLER), so the autopilot's GCS failsafe watches the
        operator's ground station, not the edge.
    """

    def __init__(
        self,
        uav: int,
        connection: str,
        home: Vec3 = (0.0, 0.0, 0.0),
        rate_hz: float = 20.0,
        timeout_s: float = 1.5,
        *,
        params: MavlinkParams = MavlinkParams(),
        sysid: int | None = None,
        source_system: int = 255,
        source_component: int = M.MAV_COMP_ID_ONBOARD_COMPUTER,
        signing_key: str | None = None,
        gcs_endpoint: str | None = None,
        gcs_video: Any = None,
    ):
        if not (isinstance(uav, int) and 1 <= uav <= 255):
            raise ValueError("uav must be an int in 1..255")
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 0 < rate_hz <= 100):
            raise ValueError("rate_hz must be in (0, 100]")
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and 0 < timeout_s <= 60):
            raise ValueError("timeout_s must be in (0, 60]")
        if sysid is not None and not (isinstance(sysid, int) and 1 <= sysid <= 255):
            raise ValueError("sysid must be None or an int in 1..255")
        if not isinstance(params, MavlinkParams):
            raise ValueError("params must be a MavlinkParams")
        self.uav = uav
        self.connection = connection
        self.home = check_vec3(home, "home")
        self.rate_hz = float(rate_hz)
        self.timeout_s = float(timeout_s)
        self.params = params
        self._home = np.array(self.home)
        self._sysid = sysid
        self._compid = M.MAV_COMP_ID_AUTOPILOT1
        self._hb_type = M.MAV_TYPE_GCS
        if gcs_endpoint is not None:
            self._hb_type = M.MAV_TYPE_ONBOARD_CONTROLLER
            if source_system == 255:
                source_system = uav
        self._conn = open_connection(connection, source_system, source_component)
        self.bridge = None
        if signing_key is not None:
            enable_signing(self._conn, parse_key(signing_key))
        self._mono0 = time.monotonic()
        self._lock = threading.RLock()  # telemetry, phase, acks
        self._cv = threading.Condition(self._lock)
        self._send_lock = threading.Lock()
        self._cmd_lock = threading.RLock()  # one COMMAND_LONG (or mode-switch sequence) in flight
        self._stop = threading.Event()
        self._closed = False
        # telemetry
        self._rx = 0
        self._hb: _Heartbeat | None = None
        self._pos: Vec3 = self.home
        self._vel: Vec3 = (0.0, 0.0, 0.0)
        self._att: Vec3 = (0.0, 0.0, 0.0)
        self._rates: Vec3 = (0.0, 0.0, 0.0)
        self._battery = 1.0
        self._last_mono: dict[str, float] = {}
        self._texts: deque[tuple[float, int, str]] = deque(maxlen=16)
        self._acks: dict[int, tuple[int, int]] = {}  # command -> (result, rx)
        self._cmd_rx = 0  # receive index of the last accepted command's ack
        self._compid_locked = False
        # readiness: EKF_STATUS_REPORT flags, SYS_STATUS pre-arm bit, the latest "not ready" text
        self._ekf_flags: int | None = None
        self._prearm_ok: bool | None = None
        self._not_ready_text = ""
        self._legacy_streams = False
        # AUTO flight: the autopilot's home, the mission protocol's replies, the uploaded plan
        self._home_lla: tuple[float, float, float] | None = None
        self._mission_rx: deque[Any] = deque(maxlen=64)
        self._auto_plan: Any = None
        self._auto_traj: Trajectory | None = None
        self._traj: Trajectory | None = None
        self._end_switch = False  # the AUTO mission ended: back to GUIDED to hold there
        self._end_mono = 0.0  # when the trajectory's clock ran out in AUTO
        self._reached_seq = -1  # the autopilot's latest MISSION_ITEM_REACHED
        # parameters: the latest PARAM_VALUE per name and the names answered PARAM_ERROR (receive index)
        self._param_rx: dict[str, tuple[float, int]] = {}
        self._param_err: dict[str, int] = {}
        #: the autopilot's parameter naming scheme ("4.6" or "4.7", :mod:`.apm.params`); None until learnt
        self.param_scheme: str | None = None
        self._pending: set[int] = set()  # autopilot modes accepted while a mode switch is in flight
        self._switching = False
        self._speed_sent: tuple[float, float] | None = None  # (speed, monotonic) of the last DO_CHANGE_SPEED
        #: DO_CHANGE_SPEED corrections sent in AUTO; mode switches to AUTO that failed (with why)
        self.speed_commands = 0
        self.auto_errors: list[str] = []
        #: autopilot modes the driver did not command and noticed (ArduCopter names, in order)
        self.external_modes: list[str] = []
        #: the autopilot's MAV_AUTOPILOT (from its HEARTBEAT; None until heard)
        self.autopilot: int | None = None
        #: undecodable datagrams, malformed values and send errors on the link
        self.link_errors = 0
        # mission state (driver phases: idle, landed, takeoff, hold, mission, land, rtl, external)
        self._t = 0.0
        self._phase = "idle"
        self._takeoff_z = self.home[2]
        self._takeoff_yaw = 0.0
        self._hold: tuple[Vec3, float] = (self.home, 0.0)  # position, ENU yaw
        #: the trajectory, its start/pause/resume, the formation offset and the captures (under _lock)
        self.mission = MissionSequencer(
            uav, self.home[2], transit_speed=params.transit_speed, start_radius=params.start_radius,
            arrive_radius=params.arrive_radius, max_offset=params.max_offset, offset_rate=params.offset_rate,
            interpolation=params.interpolation)
        self._next_target_mono = -math.inf
        #: position targets sent (count) and the last one (NED x, y, z, yaw), for inspection
        self.targets_sent = 0
        self.last_target: tuple[float, float, float, float] | None = None
        if gcs_endpoint is not None:
            from edge.vehicle.gcs_bridge import GcsBridge

            self.bridge = GcsBridge(gcs_endpoint, self._write_raw, video=gcs_video)
        self._reader = threading.Thread(target=self._read_loop, name=f"mavlink-uav{uav}", daemon=True)
        self._reader.start()

    # ------------------------------------------------------------------ link
    def _send(self, name: str, *args: Any) -> None:
        with self._send_lock:
            try:
                getattr(self._conn.mav, name)(*args)
            except OSError:
                self.link_errors += 1

    def _write_raw(self, frame: bytes) -> None:
        """One raw frame to the autopilot (from the ground-station bridge)."""
        with self._send_lock:
            self._conn.write(frame)

    def _read_loop(self) -> None:
        conn = self._conn
        last_hb = -math.inf
        last_req = -math.inf
        heard = False
        while not self._stop.is_set():
            try:
                msg = conn.recv_msg()
            except Exception:  # a malformed datagram or a closed socket must not kill the reader
                if self._stop.is_set():
                    break
                self.link_errors += 1
                msg = None
            now = time.monotonic()
            if msg is not None:
                if not heard:  # the first packet: a udpin link can answer now, so say we are here at once
                    heard, last_hb = True, -math.inf
                if self.bridge is not None:
                    self.bridge.to_gcs(msg)
                self._on_message(msg, now)
            else:
                conn.select(0.02)
            if now - last_hb >= 1.0:
                last_hb = now
                self._send("heartbeat_send", self._hb_type, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
            if self._hb is not None and now - last_req >= 2.0:
                last_req = now
                self._request_streams(now)

    def _request_streams(self, now: float) -> None:
        """Ask (again) for every telemetry message not heard lately (fire and forget): SET_MESSAGE_INTERVAL,
        or REQUEST_DATA_STREAM for its group once the autopilot refused SET_MESSAGE_INTERVAL."""
        groups: set[tuple[int, int]] = set()
        for name, (msg_id, hz) in STREAMS.items():
            if now - self._last_mono.get(name, -math.inf) <= max(1.0, 2.5 / hz):
                continue
            if not self._legacy_streams:
                self._send("command_long_send", self._sysid, self._compid, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                           msg_id, 1e6 / hz, 0, 0, 0, 0, 0)
            elif name in LEGACY_STREAMS:
                groups.add(LEGACY_STREAMS[name])
            elif name == "HOME_POSITION":
                self._send("command_long_send", self._sysid, self._compid, M.MAV_CMD_GET_HOME_POSITION, 0,
                           0, 0, 0, 0, 0, 0, 0)
        for group, hz in sorted(groups):
            self._send("request_data_stream_send", self._sysid, self._compid, group, hz, 1)

    def _on_message(self, msg: Any, now: float) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.link_errors += 1
            return
        src = msg.get_srcSystem()
        if kind == "HEARTBEAT":
            if msg.autopilot == M.MAV_AUTOPILOT_INVALID:
                return  # a GCS or another companion, not a vehicle
            comp = msg.get_srcComponent()
            with self._cv:
                if self._sysid is None:
                    self._sysid = src
                if src != self._sysid:
                    return
                if not self._compid_locked:  # the first autopilot component heard (not a gimbal or camera)
                    self._compid, self._compid_locked = comp, True
                    self.autopilot = int(msg.autopilot)
                if comp != self._compid:
                    return
                self._rx += 1
                self._hb = _Heartbeat(bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED), int(msg.custom_mode),
                                      self._rx, now, int(msg.system_status))
                self._last_mono[kind] = now
                self._cv.notify_all()
            return
        if src != self._sysid:
            return
        with self._cv:
            self._last_mono[kind] = now
            if kind == "LOCAL_POSITION_NED":
                try:
                    p = ned_to_enu((msg.x, msg.y, msg.z)) + self._home
                    v = ned_to_enu((msg.vx, msg.vy, msg.vz))
                except ValueError:
                    self.link_errors += 1
                    return
                self._pos = (float(p[0]), float(p[1]), float(p[2]))
                self._vel = (float(v[0]), float(v[1]), float(v[2]))
            elif kind == "ATTITUDE":
                try:
                    self._att = attitude_ned_to_enu(msg.roll, msg.pitch, msg.yaw)
                except ValueError:
                    self.link_errors += 1
                    return
                self._rates = rates_frd_to_flu(msg.rollspeed, msg.pitchspeed, msg.yawspeed)
            elif kind == "SYS_STATUS":
                if 0 <= msg.battery_remaining <= 100:
                    self._battery = msg.battery_remaining / 100.0
                bit = M.MAV_SYS_STATUS_PREARM_CHECK
                if msg.onboard_control_sensors_present & bit and msg.onboard_control_sensors_enabled & bit:
                    self._prearm_ok = bool(msg.onboard_control_sensors_health & bit)
            elif kind == "MISSION_ITEM_REACHED":
                self._reached_seq = max(self._reached_seq, int(msg.seq))
            elif kind == "EKF_STATUS_REPORT":
                self._ekf_flags = int(msg.flags)
            elif kind == "STATUSTEXT":
                text = msg.text.decode(errors="replace") if isinstance(msg.text, bytes) else str(msg.text)
                text = text.rstrip("\x00")
                self._texts.append((now, int(msg.severity), text))
                if any(k in text for k in _NOT_READY_TEXTS):
                    self._not_ready_text = text[:200]
            elif kind == "HOME_POSITION":
                lla = (msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1e3)
                if abs(lla[0]) <= 90 and abs(lla[1]) <= 180:
                    self._home_lla = lla
                    self._cv.notify_all()
            elif kind == "PARAM_VALUE":
                name = _param_id(msg.param_id)
                if name and math.isfinite(msg.param_value) and len(self._param_rx) < 4096:
                    self._rx += 1
                    self._param_rx[name] = (float(msg.param_value), self._rx)
                    self._cv.notify_all()
                elif name:
                    self.link_errors += 1
            elif kind == "PARAM_ERROR":
                name = _param_id(msg.param_id)
                if msg.target_system == self._conn.mav.srcSystem and name and len(self._param_err) < 4096:
                    self._rx += 1
                    self._param_err[name] = self._rx
                    self._cv.notify_all()
            elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"):
                if msg.target_system == self._conn.mav.srcSystem:
                    self._mission_rx.append(msg)
                    self._cv.notify_all()
            elif kind == "COMMAND_ACK":
                if (msg.command == M.MAV_CMD_SET_MESSAGE_INTERVAL and not self._legacy_streams
                        and msg.result in (M.MAV_RESULT_UNSUPPORTED, M.MAV_RESULT_FAILED)):
                    self._legacy_streams = True
                    log.info("UAV %d: the autopilot refused SET_MESSAGE_INTERVAL: asking with REQUEST_DATA_STREAM",
                             self.uav)
                self._rx += 1
                self._acks[int(msg.command)] = (int(msg.result), self._rx)
                self._cv.notify_all()

    def readiness(self) -> AutopilotReadiness:
        """The autopilot's readiness to fly (see the module docstring), with its own reason when not ready."""
        with self._lock:
            hb, home, flags, prearm, text = self._hb, self._home_lla, self._ekf_flags, self._prearm_ok, \
                self._not_ready_text
            local = "LOCAL_POSITION_NED" in self._last_mono
        heard = self.link_ok
        e = M.enums["MAV_STATE"].get(hb.status) if hb is not None else None
        status = e.name.removeprefix("MAV_STATE_").lower() if e is not None else ""
        booting = hb is None or hb.status in (M.MAV_STATE_UNINIT, M.MAV_STATE_BOOT, M.MAV_STATE_CALIBRATING)
        position = position_ok(flags) if flags is not None else (home is not None and local)
        armable = prearm is not False
        home_ok = home is not None
        ready = heard and not booting and home_ok and position and armable
        why = ""
        if not ready:
            if not heard:
                why = str(self._link_error() or "no HEARTBEAT")
            elif booting:
                why = f"the autopilot is starting (system status {status or 'unknown'})"
            elif not home_ok:
                why = "no home position yet"
            elif not position:
                why = "no absolute position estimate yet (EKF not using GPS)"
            else:
                why = "its pre-arm checks fail"
            if text and heard:
                why += f"; the autopilot says: {text}"
        return AutopilotReadiness(ready=ready, heartbeat=heard, status=status, home=home_ok, position=position,
                                  armable=armable, reason=why[:256])

    def heartbeat_age(self) -> float | None:
        """Seconds since the last autopilot HEARTBEAT (None: none yet)."""
        hb = self._hb
        return None if hb is None else time.monotonic() - hb.mono

    @property
    def link_ok(self) -> bool:
        """An autopilot HEARTBEAT arrived within ``heartbeat_timeout_s``."""
        age = self.heartbeat_age()
        return age is not None and age <= self.params.heartbeat_timeout_s

    @property
    def target_system(self) -> int | None:
        """The autopilot's system id (None until heard)."""
        return self._sysid

    @property
    def autopilot_mode(self) -> int | None:
        """The autopilot's custom mode from its last HEARTBEAT."""
        hb = self._hb
        return None if hb is None else hb.custom_mode

    @property
    def status_texts(self) -> list[str]:
        """The autopilot's recent STATUSTEXT messages, oldest first."""
        with self._lock:
            return [t for _, _, t in self._texts]

    def _link_error(self) -> VehicleLinkError | None:
        age = self.heartbeat_age()
        if age is None:
            waited = time.monotonic() - self._mono0
            return VehicleLinkError(f"no HEARTBEAT from an autopilot on {self.connection} in {waited:.1f} s: "
                                    "is the vehicle connected and sending to this endpoint?")
        if age > self.params.heartbeat_timeout_s:
            return VehicleLinkError(f"autopilot link lost: last HEARTBEAT {age:.1f} s ago on {self.connection}")
        if self.autopilot != M.MAV_AUTOPILOT_ARDUPILOTMEGA:
            e = M.enums["MAV_AUTOPILOT"].get(self.autopilot)
            return VehicleLinkError(f"the autopilot is {e.name if e else self.autopilot}: this driver speaks "
                                    "ArduCopter's modes only")
        return None

    def wait_heartbeat(self, timeout_s: float = 5.0) -> None:
        """Block until an autopilot HEARTBEAT is heard; :class:`VehicleLinkError` after ``timeout_s``."""
        if not (math.isfinite(timeout_s) and timeout_s >= 0):
            raise ValueError("timeout_s must be finite and >= 0")
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while not self.link_ok:
                left = deadline - time.monotonic()
                if left <= 0:
                    err = self._link_error()
                    assert err is not None
                    raise err
                self._cv.wait(min(left, 0.1))

    def _command(self, command: int, params: tuple[float, ...], what: str) -> None:
        """Send a COMMAND_LONG and wait for its COMMAND_ACK; ValueError unless MAV_RESULT_ACCEPTED."""
        err = self._link_error()
        if err is not None:
            raise err
        p = tuple(float(x) for x in params) + (0.0,) * (7 - len(params))
        with self._cmd_lock:
            got: tuple[int, int] | None = None
            sent_mono = time.monotonic()
            for attempt in range(self.params.retries + 1):
                with self._cv:
                    self._acks.pop(command, None)
                self._send("command_long_send", self._sysid, self._compid, command, attempt, *p)
                deadline = time.monotonic() + self.timeout_s
                with self._cv:
                    while True:
                        a = self._acks.pop(command, None)
                        if a is not None:
                            if a[0] != M.MAV_RESULT_IN_PROGRESS:
                                got = a
                                break
                            deadline = time.monotonic() + self.timeout_s
                        left = deadline - time.monotonic()
                        if left <= 0:
                            break
                        self._cv.wait(left)
                if got is not None:
                    break
        if got is None:
            raise VehicleLinkError(f"{what}: no COMMAND_ACK to {command_name(command)} within "
                                   f"{self.timeout_s:g} s x {self.params.retries + 1} attempts")
        result, rx = got
        if result != M.MAV_RESULT_ACCEPTED:
            with self._lock:
                texts = [t for m, _, t in self._texts if m >= sent_mono - 1.0]
            why = f" ({'; '.join(texts)})" if texts else ""
            raise ValueError(f"{what} refused by the autopilot: {result_name(result)} to "
                             f"{command_name(command)}{why}")
        with self._lock:
            self._cmd_rx = max(self._cmd_rx, rx)

    def _set_mode(self, mode: CopterMode) -> None:
        self._command(M.MAV_CMD_DO_SET_MODE, (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, int(mode)),
                      f"set mode {mode.name}")

    def _ensure_guided(self) -> None:
        """DO_SET_MODE GUIDED unless the driver already flies in GUIDED (and no newer HEARTBEAT disagrees)."""
        with self._lock:
            hb = self._hb
            fresh = hb is not None and hb.rx > self._cmd_rx
            if self._phase in ("hold", "mission", "takeoff") and not (fresh and hb.custom_mode != CopterMode.GUIDED):
                return
        self._set_mode(CopterMode.GUIDED)

    # ------------------------------------------------------------------ mode machine
    def _update_phase(self) -> None:
        """Let a HEARTBEAT newer than the last accepted command overrule the driver's phase."""
        hb = self._hb
        if hb is None or hb.rx <= self._cmd_rx:
            return
        phase = self._phase
        if not hb.armed:
            if phase not in ("idle", "landed"):
                self.mission.pause(self._t)
                self._phase = "landed"
            return
        if phase in ("idle", "landed"):
            self._phase = "external"  # armed by someone else
        elif phase == "external":
            if hb.custom_mode == CopterMode.GUIDED:
                self._hold_here()
        elif hb.custom_mode != _PHASE_COPTER[phase] and hb.custom_mode not in self._pending:
            self.external_modes.append(copter_mode_name(hb.custom_mode))
            log.warning("UAV %d: the autopilot is in %s, a mode the edge did not command (pilot or failsafe): "
                        "the mission is paused and the edge stops commanding until resumed", self.uav,
                        copter_mode_name(hb.custom_mode))
            self.mission.pause(self._t)
            if hb.custom_mode == CopterMode.GUIDED:
                self._hold_here()
            else:
                self._phase = "external"

    def _mode(self) -> Mode:
        if not self.link_ok:
            return Mode.FAILSAFE
        if self._phase == "external":
            hb = self._hb
            return copter_mode(hb.custom_mode) if hb is not None else Mode.FAILSAFE
        return _PHASE_MODE[self._phase]

    def _require(self, allowed: tuple[Mode, ...], what: str) -> Mode:
        if self._closed:
            raise ValueError("driver is closed")
        if self.heartbeat_age() is None and self.params.appear_timeout_s > 0:
            try:  # not heard yet: give the autopilot time to appear instead of a fixed window
                self.wait_heartbeat(self.params.appear_timeout_s)
            except VehicleLinkError:
                pass  # reported below
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
        hb = self._hb
        if hb is not None and hb.rx > self._cmd_rx:
            return hb.armed
        return self._phase not in ("idle", "landed")

    # ------------------------------------------------------------------ state
    def state(self) -> DriverState:
        with self._lock:
            self._update_phase()
            wp, prog = self.mission.progress(self._t)
            return DriverState(
                t=self._t, pos=self._pos, vel=self._vel, att=self._att, rates=self._rates,
                mode=self._mode(), armed=self._armed(), battery=self._battery,
                wp_index=wp, progress=prog, captures=self.mission.captures,
            )

    # ------------------------------------------------------------------ commands
    def upload(self, traj: Trajectory) -> None:
        if self.heartbeat_age() is None and self._phase == "idle" and not self._closed:
            with self._lock:  # before the autopilot appears: stored here, flown once it is there
                self.mission.load(traj)
                self._traj = traj
            return
        self._require((Mode.IDLE, Mode.LANDED, Mode.TAKEOFF, Mode.HOLD), "upload a trajectory")
        with self._lock:
            self.mission.load(traj)
            self._traj = traj

    def takeoff(self, altitude: float) -> None:
        self._require(_GROUNDED, "take off")
        altitude = float(altitude)
        if not (math.isfinite(altitude) and 0.5 <= altitude <= 500.0):
            raise ValueError("takeoff altitude must be in [0.5, 500] m")
        self._set_mode(CopterMode.GUIDED)
        self._command(M.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "arm")
        try:
            self._command(M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, math.nan, 0, 0, altitude), f"take off to {altitude:g} m")
        except ValueError:
            try:  # do not leave the motors armed on the ground
                self._command(M.MAV_CMD_COMPONENT_ARM_DISARM, (0.0,), "disarm")
            except ValueError:
                pass
            raise
        with self._lock:
            self._phase = "takeoff"
            self._takeoff_z = self.home[2] + altitude
            self._takeoff_yaw = self._att[2]

    def start(self, t0: float | None = None) -> None:
        self._require((Mode.HOLD,), "start a mission")
        self.mission.check_start(t0)
        if self.params.flight == "auto":
            self._prepare_auto()
        self._ensure_guided()
        with self._lock:
            self.mission.start(self._t, self._pos, t0)
            self._phase = "mission"
            self._next_target_mono = -math.inf

    def hold(self) -> None:
        self._require(_AIRBORNE, "hold")
        if self._phase == "hold":
            return
        if not self._armed():
            raise ValueError("cannot hold: the vehicle is not armed")
        self._ensure_guided()
        with self._lock:
            self.mission.pause(self._t)
            self._hold_here()

    def resume(self) -> None:
        self._require((Mode.HOLD,), "resume")
        self.mission.check_resume()
        self._ensure_guided()
        with self._lock:
            self.mission.resume(self._t, self._pos, self._att[2])  # flies back keeping its heading
            self._phase = "mission"
            self._next_target_mono = -math.inf

    def land(self) -> None:
        self._require(_AIRBORNE, "land")
        if self._phase == "land":
            return
        self._command(M.MAV_CMD_NAV_LAND, (0, 0, 0, math.nan, 0, 0, 0), "land")
        with self._lock:
            self.mission.cancel()
            self._phase = "land"

    def return_to_launch(self) -> None:
        self._require(_AIRBORNE, "return to launch")
        if self._phase == "rtl":
            return
        self._command(M.MAV_CMD_NAV_RETURN_TO_LAUNCH, (), "return to launch")
        with self._lock:
            self.mission.cancel()
            self._phase = "rtl"

    def set_reference_offset(self, offset: Vec3) -> None:
        if self._closed:
            raise ValueError("driver is closed")
        with self._lock:
            self.mission.set_offset(offset)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._reader.join(timeout=2.0)
        if self.bridge is not None:
            self.bridge.close()
        try:
            self._conn.close()
        except OSError:
            pass

    def __enter__(self) -> MavlinkDriver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ AUTO flight (edge.vehicle.auto_flight)
    def _wait_home(self, timeout_s: float = 5.0) -> tuple[float, float, float]:
        """The autopilot's HOME_POSITION (asked for with MAV_CMD_REQUEST_MESSAGE until it comes)."""
        deadline = time.monotonic() + timeout_s
        asked = -math.inf
        with self._cv:
            while self._home_lla is None:
                now = time.monotonic()
                if now >= deadline:
                    raise VehicleLinkError(f"no HOME_POSITION from the autopilot in {timeout_s:g} s")
                if now - asked >= 1.0:
                    asked = now
                    self._send("command_long_send", self._sysid, self._compid, M.MAV_CMD_REQUEST_MESSAGE, 0,
                               M.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0)
                self._cv.wait(0.1)
            return self._home_lla

    # ------------------------------------------------------------------ parameters
    def _param_exchange(self, name: str, send: tuple, timeout_s: float, retries: int) -> float | None:
        """Send ``send`` (a PARAM_REQUEST_READ or PARAM_SET) until a PARAM_VALUE of ``name`` or a PARAM_ERROR for it
        arrives after it: the value, or None for PARAM_ERROR (the parameter does not exist)."""
        if len(name) > 16 or not name.isascii():
            raise ValueError(f"bad parameter name {name!r}")
        err = self._link_error()
        if err is not None:
            raise err
        with self._cmd_lock:
            for _ in range(retries + 1):
                with self._cv:
                    rx0 = self._rx
                self._send(*send)
                deadline = time.monotonic() + timeout_s
                with self._cv:
                    while True:
                        got = self._param_rx.get(name)
                        if got is not None and got[1] > rx0:
                            return got[0]
                        if self._param_err.get(name, -1) > rx0:
                            return None
                        left = deadline - time.monotonic()
                        if left <= 0:
                            break
                        self._cv.wait(left)
        raise VehicleLinkError(f"no answer from the autopilot for parameter {name} "
                               f"({timeout_s:g} s x {retries + 1} attempts)")

    def read_param(self, name: str, timeout_s: float = 1.0, retries: int = 2) -> float | None:
        """PARAM_REQUEST_READ by name: the value as the autopilot stores it, or None when it answers PARAM_ERROR
        (no such parameter); :class:`VehicleLinkError` without an answer."""
        raw = name.encode("ascii", "replace")
        return self._param_exchange(name, ("param_request_read_send", self._sysid, self._compid, raw, -1),
                                    timeout_s, retries)

    def set_param(self, name: str, value: float, param_type: int = M.MAV_PARAM_TYPE_REAL32,
                  timeout_s: float = 1.0, retries: int = 2) -> float:
        """PARAM_SET and wait for the echoed PARAM_VALUE (ArduPilot's ints travel as float values). Raises
        ValueError when the parameter does not exist or the autopilot kept another value (refused)."""
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"parameter {name}: value must be finite")
        raw = name.encode("ascii", "replace")
        got = self._param_exchange(name, ("param_set_send", self._sysid, self._compid, raw, value, param_type),
                                   timeout_s, retries)
        if got is None:
            raise ValueError(f"parameter {name} does not exist on the autopilot")
        if not math.isclose(got, value, rel_tol=1e-6, abs_tol=1e-6):
            raise ValueError(f"parameter {name}: the autopilot kept {got:g} instead of {value:g}")
        return got

    def learn_param_scheme(self, timeout_s: float = 1.0) -> str:
        """The autopilot's parameter naming scheme (:data:`.apm.params.SCHEMES`), learnt once: read 4.7's
        WP_SPD (a rename shipped in 4.7.0); a value means "4.7"; PARAM_ERROR (or silence, as firmware before
        PARAM_ERROR) means reading 4.6's WPNAV_SPEED, whose value means "4.6"."""
        if self.param_scheme is not None:
            return self.param_scheme
        scheme = None
        for candidate in reversed(SCHEMES):
            try:
                value = self.read_param(param_name("wp_speed", candidate), timeout_s=timeout_s, retries=1)
            except VehicleLinkError:
                if candidate == SCHEMES[0]:
                    raise
                continue
            if value is not None:
                scheme = candidate
                break
        if scheme is None:
            raise ValueError("the autopilot has neither WP_SPD nor WPNAV_SPEED: unknown parameter scheme")
        self.param_scheme = scheme
        log.info("UAV %d: autopilot parameters in ArduCopter %s's naming scheme", self.uav, scheme)
        return scheme

    def _spelling(self, key: str) -> tuple[str, str, float]:
        """(name, scheme of that name, current raw value) of renamed parameter ``key``: the learnt scheme's
        name, else the other scheme's (firmware mid-way through the renames, e.g. 4.7.0 kept SYSID_THISMAV)."""
        first = self.learn_param_scheme()
        for scheme in (first, *(x for x in SCHEMES if x != first)):
            name = param_name(key, scheme)
            raw = self.read_param(name)
            if raw is not None:
                return name, scheme, raw
        raise ValueError(f"the autopilot has no parameter {' or '.join(param_name(key, x) for x in SCHEMES)}")

    def read_param_si(self, key: str) -> float:
        """Renamed parameter ``key`` (:data:`.apm.params.RENAMED`, e.g. "wp_speed") in SI units (m, m/s)."""
        _, scheme, raw = self._spelling(key)
        return from_raw(key, raw, scheme)

    def set_param_si(self, key: str, si: float) -> float:
        """Set renamed parameter ``key`` from a value in SI units, in the autopilot's name and unit; the value
        stored, in SI units."""
        name, scheme, _ = self._spelling(key)
        ptype = param_type(key, scheme)
        raw = to_raw(key, si, scheme)
        if ptype != M.MAV_PARAM_TYPE_REAL32:
            raw = float(round(raw))
        return from_raw(key, self.set_param(name, raw, ptype), scheme)

    def set_waypoint_speed(self, speed: float) -> float:
        """The autopilot's default waypoint speed (WPNAV_SPEED cm/s in 4.6, WP_SPD m/s in 4.7), m/s."""
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError("waypoint speed must be finite and > 0")
        return self.set_param_si("wp_speed", speed)

    def _default_speed(self, items: tuple) -> None:
        """Make the plan's first leg speed the autopilot's waypoint speed too: ArduCopter starts (and re-enters)
        AUTO at WPNAV_SPEED / WP_SPD until the next DO_CHANGE_SPEED item. Best effort: a warning if refused."""
        speed = next((it.param2 for it in items if it.command == AI.MAV_CMD_DO_CHANGE_SPEED
                      and math.isfinite(it.param2) and it.param2 > 0), None)
        if speed is None:
            return
        try:
            got = self.set_waypoint_speed(min(float(speed), 20.0))
        except ValueError as exc:
            log.warning("UAV %d: the autopilot's waypoint speed was not set: %s", self.uav, exc)
            return
        log.info("UAV %d: waypoint speed %.2f m/s set as %s (ArduCopter %s parameter names)", self.uav, got,
                 param_name("wp_speed", self.param_scheme or SCHEMES[0]), self.param_scheme)

    def _prepare_auto(self) -> None:
        """Upload the trajectory as a waypoint mission unless the autopilot already has it."""
        from edge.vehicle.auto_flight import autopilot_mission

        traj = self._traj
        if traj is None:
            raise ValueError("no trajectory uploaded")
        if self._auto_traj is traj and self._auto_plan is not None:
            return
        plan = autopilot_mission(traj, self.home, self._wait_home())
        self._upload_items(plan.items)
        self._default_speed(plan.items)
        with self._lock:
            self._reached_seq = -1
        self._auto_plan, self._auto_traj = plan, traj
        log.info("UAV %d: trajectory uploaded to the autopilot as a mission of %d items (%d waypoints, %d captures)",
                 self.uav, len(plan.items), len(set(plan.waypoint_seq)), len(plan.capture_seq))

    def _upload_items(self, items: tuple, timeout_s: float = 1.0, retries: int = 5) -> None:
        """The MAVLink mission protocol's upload (https://mavlink.io/en/services/mission.html):
        MISSION_COUNT, then MISSION_ITEM_INT for each MISSION_REQUEST(_INT), until MISSION_ACK."""
        n = len(items)
        with self._cmd_lock:
            with self._cv:
                self._mission_rx.clear()
            self._send("mission_count_send", self._sysid, self._compid, n, M.MAV_MISSION_TYPE_MISSION)
            tries, deadline = 0, time.monotonic() + timeout_s
            while True:
                with self._cv:
                    while not self._mission_rx and time.monotonic() < deadline:
                        self._cv.wait(max(0.0, deadline - time.monotonic()))
                    msg = self._mission_rx.popleft() if self._mission_rx else None
                if msg is None:
                    tries += 1
                    if tries > retries:
                        raise VehicleLinkError(f"mission upload: no answer from the autopilot after {tries} tries")
                    self._send("mission_count_send", self._sysid, self._compid, n, M.MAV_MISSION_TYPE_MISSION)
                    deadline = time.monotonic() + timeout_s
                    continue
                if msg.get_type() == "MISSION_ACK":
                    if msg.type != M.MAV_MISSION_ACCEPTED:
                        e = M.enums["MAV_MISSION_RESULT"].get(int(msg.type))
                        raise ValueError(f"mission upload refused by the autopilot: {e.name if e else msg.type}")
                    return
                seq = int(msg.seq)
                if 0 <= seq < n:
                    it = items[seq]
                    self._send("mission_item_int_send", self._sysid, self._compid, seq, it.frame, it.command,
                               int(seq == 0), 1, it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z,
                               M.MAV_MISSION_TYPE_MISSION)
                deadline = time.monotonic() + timeout_s

    def _switch_async(self, mode: CopterMode, seq: int | None, expect: str) -> None:
        """DO_SET_MISSION_CURRENT (``seq``) and DO_SET_MODE ``mode`` off the caller's thread (step never
        waits for the link), while the driver stays in phase ``expect``; either mode is accepted meanwhile."""
        with self._lock:
            if self._switching:
                return
            self._switching = True
            self._pending = {int(mode), *([CopterMode.GUIDED] if mode == CopterMode.AUTO else [CopterMode.AUTO])}

        def run() -> None:
            try:
                with self._cmd_lock:
                    with self._lock:
                        if self._phase != expect:
                            return  # a command (hold, land, ...) came first
                    if seq is not None:
                        try:
                            self._command(M.MAV_CMD_DO_SET_MISSION_CURRENT, (float(seq),), "set the mission item")
                        except ValueError as exc:  # before ArduPilot 4.4: the MISSION_SET_CURRENT message
                            if "UNSUPPORTED" not in str(exc):
                                raise
                            self._send("mission_set_current_send", self._sysid, self._compid, int(seq))
                    self._set_mode(mode)
                    with self._lock:
                        if self._phase == expect and mode == CopterMode.AUTO:
                            self._phase = "auto"
                            self._speed_sent = None
                    log.info("UAV %d: flying %s%s", self.uav, mode.name,
                             f" from mission item {seq}" if seq is not None else " (the AUTO mission ended: hold)")
            except ValueError as exc:
                self.auto_errors.append(str(exc))  # AUTO refused: the mission goes on in GUIDED
                log.warning("UAV %d: mode switch to %s failed: %s", self.uav, mode.name, exc)
            finally:
                with self._lock:
                    self._switching = False
                    self._pending = set()

        threading.Thread(target=run, name=f"mavlink-uav{self.uav}-switch", daemon=True).start()

    def _auto_finished(self) -> bool:
        """The autopilot reached the mission's last waypoint (its capture items ran), or
        ``auto_end_wait_s`` passed since the trajectory's clock ran out (under ``_lock``)."""
        plan = self._auto_plan
        last = max(plan.waypoint_seq) if plan is not None and plan.waypoint_seq else -1
        return self._reached_seq >= last or time.monotonic() - self._end_mono > self.params.auto_end_wait_s

    def _auto_step(self, target: _Target) -> None:
        """One AUTO tick: the formation-keeping speed (DO_CHANGE_SPEED, fire and forget)."""
        from edge.vehicle.auto_flight import speed_correction

        p, v, _, _ = target
        if v is None:
            return
        speed = speed_correction(self._pos, p, v, gain=self.params.auto_speed_gain)
        if speed is None:
            return
        now = time.monotonic()
        last = self._speed_sent
        if last is not None and now - last[1] < self.params.auto_speed_period_s and abs(speed - last[0]) < 0.5:
            return
        self._speed_sent = (speed, now)
        self.speed_commands += 1
        self._send("command_long_send", self._sysid, self._compid, M.MAV_CMD_DO_CHANGE_SPEED, 0,
                   *AI.speed_params(min(speed, 20.0)))

    # ------------------------------------------------------------------ mission bookkeeping (under _lock)
    def _hold_here(self) -> None:
        self._phase = "hold"
        self._hold = (self._pos, self._att[2])
        self._next_target_mono = -math.inf

    def _fire(self, due: list, t: float, events: list[CaptureEvent]) -> None:
        for w in due:
            events.append(CaptureEvent(w.capture_id, t, self._pos, self._att))

    def _mission_reference(self, t: float, dt: float, events: list[CaptureEvent]) -> _Target:
        """The mission's target at time t (the sequencer's reference, as this driver streams it).

        Waiting at the first waypoint and holding at the end: position and yaw; transit:
        position, velocity and yaw; tracking: also the acceleration (``accel_feedforward``).
        """
        m = self.mission
        p, v, a, yaw = m.reference(t, self._pos, dt)
        due = m.due(t)
        if due:
            self._fire(due, t, events)
        if m.done:
            self._phase = "hold"
            self._hold = (p, yaw)
            return p, None, None, yaw
        phase = m.phase
        if phase == "track":
            return p, v, (a if self.params.accel_feedforward else None), yaw
        if phase == "wait":
            return p, None, None, yaw
        return p, v, None, yaw

    # ------------------------------------------------------------------ streaming
    def step(self, until_t: float) -> list[CaptureEvent]:
        if self._closed:
            raise ValueError("driver is closed")
        until_t = float(until_t)
        if not math.isfinite(until_t):
            raise ValueError("until_t must be finite")
        events: list[CaptureEvent] = []
        target: _Target | None = None
        auto_target: _Target | None = None
        with self._lock:
            dt = until_t - self._t
            self._t = until_t
            self._update_phase()
            if not self.link_ok:
                return events
            phase = self._phase
            if (phase == "takeoff" and self._pos[2] >= self._takeoff_z - self.params.takeoff_tolerance
                    and abs(self._vel[2]) < 0.3):
                self._phase = phase = "hold"
                self._hold = ((self._pos[0], self._pos[1], self._takeoff_z), self._takeoff_yaw)
                self._next_target_mono = -math.inf
            if phase == "mission":
                target = self._mission_reference(until_t, dt, events)
                if (self.params.flight == "auto" and self._auto_plan is not None and self.mission.phase == "track"
                        and not self._switching):
                    from edge.vehicle.auto_flight import resume_item

                    wp, _ = self.mission.progress(until_t)
                    self._switch_async(CopterMode.AUTO, resume_item(self._auto_plan, wp), "mission")
            elif phase == "auto":
                ref = self._mission_reference(until_t, dt, events)
                if self._phase == "hold":  # the trajectory's end: hold there in GUIDED once AUTO finished
                    self._end_switch = True
                    self._end_mono = time.monotonic()
                    self._pending = {int(CopterMode.AUTO)}
                    phase = "hold"
                else:
                    auto_target = ref
            if phase == "hold" and self._end_switch and not self._switching and self._auto_finished():
                self._end_switch = False
                self._switch_async(CopterMode.GUIDED, None, "hold")
            if phase == "hold":
                target = (self._hold[0], None, None, self._hold[1])
            # at most rate_hz on average; a tick up to 20 % of a period early still sends, so a board
            # ticking at exactly rate_hz is not halved by jitter
            now, period = time.monotonic(), 1.0 / self.rate_hz
            if target is not None and now < self._next_target_mono - 0.2 * period:
                target = None  # streamed recently enough
            if target is not None:
                due = self._next_target_mono
                self._next_target_mono = due + period if now - due < period else now + period
        if target is not None:
            self._send_target(*target)
        if auto_target is not None:
            self._auto_step(auto_target)
        if self.params.trigger_camera:
            for ev in events:
                self._send("command_long_send", self._sysid, self._compid, M.MAV_CMD_DO_DIGICAM_CONTROL, 0,
                           *capture_params(ev.capture_id))
        return events

    def _send_target(self, pos: Vec3, vel: Vec3 | None, acc: Vec3 | None, yaw_enu: float) -> None:
        """SET_POSITION_TARGET_LOCAL_NED for an ENU position (+ velocity, + acceleration) and yaw."""
        h = self.home
        x, y, z = pos[1] - h[1], pos[0] - h[0], -(pos[2] - h[2])
        vx, vy, vz = (vel[1], vel[0], -vel[2]) if vel is not None else (0.0, 0.0, 0.0)
        ax, ay, az = (acc[1], acc[0], -acc[2]) if acc is not None else (0.0, 0.0, 0.0)
        if vel is None:
            mask = TYPE_MASK_POS_YAW
        else:
            mask = TYPE_MASK_POS_VEL_YAW if acc is None else TYPE_MASK_POS_VEL_ACC_YAW
        yaw = yaw_enu_to_ned(yaw_enu)
        ms = int((time.monotonic() - self._mono0) * 1000) & 0xFFFFFFFF
        self._send("set_position_target_local_ned_send", ms, self._sysid, self._compid, M.MAV_FRAME_LOCAL_NED,
                   mask, x, y, z, vx, vy, vz, ax, ay, az, yaw, 0)
        self.targets_sent += 1
        self.last_target = (x, y, z, yaw)
