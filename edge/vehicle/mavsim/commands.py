"""How the sim autopilot obeys: COMMAND_LONG / COMMAND_INT as a table from MAV_CMD to handler, SET_MODE,
arming, takeoff, the current mission item, DO_REPOSITION and GUIDED position targets (ArduCopter's rules,
:mod:`edge.vehicle.apm.modes`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as M

from edge.geometry import ardupilot_items as I
from edge.vehicle.angles import wrap_angle
from edge.vehicle.apm.auto import AutoMission
from edge.vehicle.apm.missions import PlanItem
from edge.vehicle.apm.modes import ARMABLE, CopterMode, check_mode_change
from edge.vehicle.follower import Reference
from protocol.messages import Mode

__all__ = ["GuidedTarget", "GUIDED_TIMEOUT_S", "SimCommands", "COMMANDS"]

Vec3 = tuple[float, float, float]
#: a guided velocity target older than this is dropped (ArduCopter's guided pos/vel timeout), s
GUIDED_TIMEOUT_S = 3.0
#: ArduPilot's "force" code in param2 of COMPONENT_ARM_DISARM
FORCE_CODE = 21196
_ZERO: Vec3 = (0.0, 0.0, 0.0)
ACCEPTED, DENIED, FAILED, UNSUPPORTED = (M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_DENIED, M.MAV_RESULT_FAILED,
                                         M.MAV_RESULT_UNSUPPORTED)


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


class SimCommands:
    """The obeying half of :class:`.vehicle.MavlinkSimVehicle` (a mixin: it uses the vehicle's state)."""

    auto: Any  # the AUTO mission being flown, or None
    custom_mode: int  # ArduCopter's flight mode number

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
        """A COMMAND_LONG (or a COMMAND_INT seen as one): the MAV_RESULT of its handler in :data:`COMMANDS`."""
        handler = COMMANDS.get(msg.command)
        return UNSUPPORTED if handler is None else handler(self, msg, is_int)

    def _mission_start(self, msg: Any, is_int: bool) -> int:
        first = int(msg.param1) if math.isfinite(msg.param1) and msg.param1 >= 1 else None
        r = self._set_mode(CopterMode.AUTO)
        if r == ACCEPTED and first is not None:
            self._set_current(first)
        return r

    def _change_speed(self, msg: Any, is_int: bool) -> int:
        ex = self.auto if self.custom_mode == CopterMode.AUTO else self._leg
        if not (math.isfinite(msg.param2) and 0 < msg.param2 <= 20):
            return DENIED
        if ex is not None:
            ex.set_speed(self.sim.t, float(msg.param2))
        return ACCEPTED

    def _digicam(self, msg: Any, is_int: bool) -> int:
        cid = I.capture_id((msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7))
        if msg.param5 == 1:
            self._shot(cid if cid is not None else len(self.shots), self.sim.state())
        return ACCEPTED

    def _get_interval(self, msg: Any, is_int: bool) -> int:
        us = self.streams.interval_us(msg.param1)
        if us is None:
            return DENIED
        self._send(M.MAVLink_message_interval_message(int(msg.param1), us))
        return ACCEPTED

    def _request_message(self, msg: Any, is_int: bool) -> int:
        if not math.isfinite(msg.param1):
            return DENIED
        mid = int(msg.param1)
        name = "AUTOPILOT_VERSION" if mid == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION else self.streams.names.get(mid)
        return ACCEPTED if name is not None and self._stream(name) else DENIED

    def _get_home(self, msg: Any, is_int: bool) -> int:
        if not self.home_known:
            return FAILED
        self._stream("HOME_POSITION")
        return ACCEPTED

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


def _ok(done: bool) -> int:
    return ACCEPTED if done else DENIED


def _int(v: float) -> int:
    """A command parameter as an integer (−1 for NaN or infinity: clients send NaN for "unused")."""
    return int(v) if math.isfinite(v) else -1


#: MAV_CMD -> handler(vehicle, command, is COMMAND_INT) -> MAV_RESULT; any other command is UNSUPPORTED
COMMANDS: dict[int, Callable[[Any, Any, bool], int]] = {
    M.MAV_CMD_DO_SET_MODE: lambda v, c, i: (v._set_mode(c.param2) if _int(c.param1) > 0
                                            and _int(c.param1) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED else UNSUPPORTED),
    M.MAV_CMD_COMPONENT_ARM_DISARM: lambda v, c, i: v._arm(c.param1 > 0.5, _int(c.param2) == FORCE_CODE),
    M.MAV_CMD_NAV_TAKEOFF: lambda v, c, i: v._takeoff(c.param7),
    M.MAV_CMD_NAV_LAND: lambda v, c, i: v._set_mode(CopterMode.LAND),
    M.MAV_CMD_NAV_RETURN_TO_LAUNCH: lambda v, c, i: v._set_mode(CopterMode.RTL),
    M.MAV_CMD_MISSION_START: SimCommands._mission_start,
    M.MAV_CMD_DO_SET_MISSION_CURRENT: lambda v, c, i: _ok(v._set_current(c.param1)),
    M.MAV_CMD_DO_REPOSITION: SimCommands._reposition,
    M.MAV_CMD_DO_CHANGE_SPEED: SimCommands._change_speed,
    M.MAV_CMD_DO_DIGICAM_CONTROL: SimCommands._digicam,
    M.MAV_CMD_SET_MESSAGE_INTERVAL: lambda v, c, i: _ok(v.streams.set_interval(c.param1, c.param2)),
    M.MAV_CMD_GET_MESSAGE_INTERVAL: SimCommands._get_interval,
    M.MAV_CMD_REQUEST_MESSAGE: SimCommands._request_message,
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: lambda v, c, i: (v._stream("AUTOPILOT_VERSION"), ACCEPTED)[1],
    M.MAV_CMD_GET_HOME_POSITION: SimCommands._get_home,
}
