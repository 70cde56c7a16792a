"""AUTO mode: walking a mission's items as ArduCopter's mission library does (a subset).

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/auto.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from edge.geometry import ardupilot_items as I
from edge.vehicle.apm import missions as W
from edge.vehicle.apm.missions import PlanItem

__all__ = ["AutoMission", "Flight", "MAV_CMD_CONDITION_YAW", "MIN_LEG_S"]

Vec3 = tuple[float, float, float]
MAV_CMD_CONDITION_YAW = 115
#: least time ArduCopter takes for a waypoint leg, s (its S-curves: see the table above)
MIN_LEG_S = 1.8
#: ArduCopter's CIRCLE_RADIUS default, m (LOITER_TURNS with radius 0)
CIRCLE_RADIUS_M = 5.0
#: items stored but not flown (see the table above)
_SKIPPED = frozenset({W.MAV_CMD_CONDITION_DELAY, W.MAV_CMD_CONDITION_DISTANCE, W.MAV_CMD_DO_SET_SERVO,
                      W.MAV_CMD_DO_LAND_START, W.MAV_CMD_DO_SET_ROI_LOCATION, W.MAV_CMD_DO_SET_ROI,
                      W.MAV_CMD_IMAGE_START_CAPTURE})


@dataclass(frozen=True)
class Flight:
    """What AUTO flies now: ``kind`` "goto" (pos, vel, yaw), "takeoff" (alt above home), "land", "rtl", "hold"."""

    kind: str
    pos: Vec3 = (0.0, 0.0, 0.0)
    vel: Vec3 = (0.0, 0.0, 0.0)
    yaw: float = 0.0
    alt: float = 0.0


def _dist(a: Vec3, b: Vec3) -> float:
    return math.dist(a, b)


class AutoMission:
    """The mission executor of the stored ``items`` (item 0, home, skipped; ``to_enu`` places a positioned
    item, altitude relative to ``home``), with WPNAV_SPEED ``speed`` (m/s), WPNAV_RADIUS ``radius`` (m),
    WP_YAW_BEHAVIOR and ``min_leg_s``, the least time a waypoint leg takes (0: the set speed whatever the length)."""

    def __init__(self, items: list[PlanItem], to_enu: Callable[[PlanItem], Vec3], home: Vec3, speed: float,
                 radius: float = 2.0, yaw_behavior: int = 2, takeoff_tol: float = 0.3, start: int = 1,
                 min_leg_s: float = MIN_LEG_S):
        self.items = list(items)
        self.to_enu = to_enu
        self.home = home
        self.speed = float(speed)
        self.radius = float(radius)
        self.yaw_behavior = int(yaw_behavior)
        self.takeoff_tol = float(takeoff_tol)
        self.min_leg_s = max(0.0, float(min_leg_s))
        self.current = max(1, int(start))
        self.done = False
        self.shots = 0
        self._leg: tuple[Vec3, Vec3, float] | None = None  # start, end, t_start
        self._leg_cap = math.inf  # the current leg's speed cap (min_leg_s), m/s
        self._hold_until: float | None = None
        self._yaw: float | None = None
        self._trig_dist = 0.0
        self._trig_from: Vec3 | None = None
        self._began = False
        self._last_target: Vec3 | None = None
        self._started: set[int] = set()
        self._takeoff_xy: tuple[float, float] | None = None
        self._t_free: float | None = None  # when the last leg's carrot arrived (plus its hold)
        self._jumps: dict[int, int] = {}  # DO_JUMP item -> jumps left
        self.jumps = 0  # DO_JUMPs taken

    def set_current(self, seq: int) -> bool:
        """MISSION_SET_CURRENT / DO_SET_MISSION_CURRENT: jump to ``seq`` (1..len-1)."""
        if not 1 <= seq < max(2, len(self.items)):
            return False
        self.current, self._leg, self._hold_until, self.done = int(seq), None, None, False
        self._started.discard(seq)
        return True

    def _leg_speed(self) -> float:
        """The speed the current leg is flown at: the set speed, capped so that the whole leg (as it was
        when it began: a speed change rebases it, not its cap) lasts ``min_leg_s``."""
        return min(self.speed, self._leg_cap)

    def set_speed(self, t: float, speed: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED as a command: the carrot goes on from where it is at the new speed
        (the leg is rebased at the carrot, so a speed change never makes it jump)."""
        if self._leg is not None:
            start, end, t0 = self._leg
            length = _dist(start, end)
            s = min(length, self._leg_speed() * max(0.0, t - t0))
            if length > 1e-9 and s < length:
                f = s / length
                carrot = tuple(b + (e - b) * f for b, e in zip(start, end))
                self._leg = (carrot, end, max(t, t0))  # type: ignore[assignment]
        self.speed = float(speed)

    def update(self, t: float, pos: Vec3, yaw: float, airborne: bool) -> tuple[Flight, list[tuple[str, int]]]:
        ev: list[tuple[str, int]] = []
        if not self._began:
            self._began = True
            ev.append(("current", self.current))
        if self._yaw is None:
            self._yaw = yaw
        self._camera_distance(pos, ev)
        for _ in range(len(self.items) + 1):  # do items run at once; stop at the first NAV item
            if self.current >= len(self.items):
                self.done = True
                return Flight("hold", self._last_target or pos, yaw=self._yaw), ev
            it = self.items[self.current]
            c = it.command
            if c in (I.MAV_CMD_DO_CHANGE_SPEED, I.MAV_CMD_DO_DIGICAM_CONTROL, I.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
                     MAV_CMD_CONDITION_YAW):
                self._do(it, t, pos, ev)
                self._advance(ev)
                continue
            if c in _SKIPPED:
                self._advance(ev)
                continue
            if c == W.MAV_CMD_DO_JUMP:
                self._jump(it, ev)
                continue
            flight, complete = self._nav(it, t, pos, airborne)
            if not complete:
                return flight, ev
            ev.append(("reached", self.current))
            self._advance(ev)
        return Flight("hold", pos, yaw=self._yaw), ev

    def _advance(self, ev: list[tuple[str, int]]) -> None:
        self.current += 1
        self._leg, self._hold_until = None, None
        if self.current < len(self.items):
            ev.append(("current", self.current))

    def _jump(self, it: PlanItem, ev: list[tuple[str, int]]) -> None:
        """DO_JUMP: to item param1 while jumps are left (param2; -1 for ever), else on to the next item."""
        target = int(it.param1) if math.isfinite(it.param1) else -1
        left = self._jumps.setdefault(self.current, int(it.param2) if math.isfinite(it.param2) else 0)
        if left == 0 or not 1 <= target < len(self.items) or target == self.current:
            self._advance(ev)
            return
        if left > 0:
            self._jumps[self.current] = left - 1
        self.jumps += 1
        self.current, self._leg, self._hold_until = target, None, None
        self._started.discard(target)
        ev.append(("current", target))

    def _do(self, it: PlanItem, t: float, pos: Vec3, ev: list[tuple[str, int]]) -> None:
        c = it.command
        if c == I.MAV_CMD_DO_CHANGE_SPEED:
            if math.isfinite(it.param2) and it.param2 > 0:
                self.speed = float(it.param2)
                if self._leg is not None:
                    self._leg = (pos, self._leg[1], t)
        elif c == I.MAV_CMD_DO_DIGICAM_CONTROL:
            cid = I.capture_id(it.params)
            if cid is not None:
                self.shots += 1
                ev.append(("shot", cid))
        elif c == I.MAV_CMD_DO_SET_CAM_TRIGG_DIST:
            self._trig_dist = max(0.0, float(it.param1)) if math.isfinite(it.param1) else 0.0
            self._trig_from = pos
            if it.param3 == 1:
                self.shots += 1
                ev.append(("shot", self.shots))
        elif c == MAV_CMD_CONDITION_YAW and math.isfinite(it.param1):
            enu = math.radians(90.0 - it.param1)
            base = self._yaw or 0.0
            self._yaw = math.remainder(base - math.radians(it.param1) if it.param4 == 1 else enu, 2 * math.pi)

    def _camera_distance(self, pos: Vec3, ev: list[tuple[str, int]]) -> None:
        if self._trig_dist <= 0 or self._trig_from is None:
            return
        if _dist(pos, self._trig_from) >= self._trig_dist:
            self._trig_from = pos
            self.shots += 1
            ev.append(("shot", self.shots))

    def _nav(self, it: PlanItem, t: float, pos: Vec3, airborne: bool) -> tuple[Flight, bool]:
        c = it.command
        if c == I.MAV_CMD_NAV_TAKEOFF:
            z = self.home[2] + max(0.5, it.z)
            if airborne and pos[2] >= z - self.takeoff_tol:
                self._last_target = (pos[0], pos[1], z)
                return Flight("hold", self._last_target, yaw=self._yaw or 0.0), True
            if self._takeoff_xy is None:
                self._takeoff_xy = (pos[0], pos[1])
            return Flight("takeoff", (*self._takeoff_xy, z), yaw=self._yaw or 0.0, alt=z - self.home[2]), False
        if c in (I.MAV_CMD_NAV_WAYPOINT, W.MAV_CMD_NAV_SPLINE_WAYPOINT, W.MAV_CMD_NAV_LOITER_TIME,
                 W.MAV_CMD_NAV_LOITER_TURNS, W.MAV_CMD_NAV_LOITER_UNLIM):
            p = self.to_enu(it)
            if it.x == 0 and it.y == 0:  # ArduPilot: lat/lon 0 = here
                p = (pos[0], pos[1], p[2])
            flight, done = self._goto(t, pos, p, hold_s=self._hold_s(it))
            return flight, done and c != W.MAV_CMD_NAV_LOITER_UNLIM
        if c == W.MAV_CMD_NAV_DELAY:
            here = self._last_target or pos
            self._last_target = here
            return self._goto(t, pos, here, hold_s=self._hold_s(it))
        if c in (I.MAV_CMD_NAV_LAND, I.MAV_CMD_NAV_RETURN_TO_LAUNCH):  # done once down again
            if not airborne and self.current in self._started:
                return Flight("hold", pos), True
            self._started.add(self.current)
            return Flight("land" if c == I.MAV_CMD_NAV_LAND else "rtl"), False
        return Flight("hold", pos), True  # a command the store let through but AUTO does not fly

    def _hold_s(self, it: PlanItem) -> float:
        """How long a NAV item holds at its point once reached, s."""
        p1 = it.param1 if math.isfinite(it.param1) else 0.0
        if it.command == W.MAV_CMD_NAV_LOITER_TURNS:
            r = abs(it.param3) if math.isfinite(it.param3) and it.param3 != 0 else CIRCLE_RADIUS_M
            return max(0.0, p1) * 2 * math.pi * r / self.speed if self.speed > 0 else 0.0
        return max(0.0, p1)

    def _goto(self, t: float, pos: Vec3, end: Vec3, hold_s: float) -> tuple[Flight, bool]:
        if self._leg is None or self._leg[1] != end:
            start = self._last_target or pos
            # a leg starts when the previous one's carrot arrived (not at the next update after it), so
            # the update rate does not stretch the mission's timing
            t0 = self._t_free if self._t_free is not None and 0.0 <= t - self._t_free < 0.5 else t
            self._leg = (start, end, t0)
            self._t_free = None
            whole = _dist(start, end)
            self._leg_cap = whole / self.min_leg_s if self.min_leg_s > 0 and whole > 0 else math.inf
            d = (end[0] - start[0], end[1] - start[1])
            if self.yaw_behavior != 0 and math.hypot(*d) > 2.0:
                self._yaw = math.atan2(d[1], d[0])
        start, end, t0 = self._leg
        length = _dist(start, end)
        speed = self._leg_speed()
        s = speed * max(0.0, t - t0)
        yaw = self._yaw or 0.0
        if length > 1e-9 and s < length:
            u = tuple((e - b) / length for b, e in zip(start, end))
            carrot = tuple(b + ui * s for b, ui in zip(start, u))
            vel = tuple(ui * speed for ui in u)
            return Flight("goto", carrot, vel, yaw), False  # type: ignore[arg-type]
        self._last_target = end
        if _dist(pos, end) > self.radius:
            return Flight("goto", end, yaw=yaw), False
        if self._hold_until is None:
            arrived = t0 + (length / speed if speed > 0 else 0.0)
            self._hold_until = max(arrived, t - 0.5) + max(0.0, hold_s)
        if t >= self._hold_until:
            self._t_free = self._hold_until
            return Flight("goto", end, yaw=yaw), True
        return Flight("goto", end, yaw=yaw), False
