"""The mission protocol (https://mavlink.io/en/services/mission.html) on the vehicle side.

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/missions.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from edge.geometry import ardupilot_items as I

__all__ = ["PlanItem", "MissionServer", "MISSION", "FENCE", "RALLY", "SUPPORTED"]

Out = tuple[str, dict]
MISSION, FENCE, RALLY = 0, 1, 2
MAV_MISSION_ACCEPTED = 0
MAV_MISSION_ERROR = 1
MAV_MISSION_UNSUPPORTED_FRAME = 2
MAV_MISSION_UNSUPPORTED = 3
MAV_MISSION_INVALID = 5
MAV_MISSION_INVALID_PARAM1 = 6
MAV_MISSION_INVALID_SEQUENCE = 13
MAV_MISSION_DENIED = 14
MAV_MISSION_OPERATION_CANCELLED = 15
#: frames with latitude/longitude in x/y
GLOBAL_FRAMES = {0, 3, 5, 6, 10, 11}
MAV_FRAME_MISSION = 2
_INT_FRAMES = {5: 0, 6: 3, 11: 10}  # the deprecated *_INT frames -> their plain counterparts

#: MAV_CMDs (common.xml) ArduCopter stores that the project's own plans do not use
MAV_CMD_NAV_LOITER_UNLIM, MAV_CMD_NAV_LOITER_TURNS, MAV_CMD_NAV_LOITER_TIME = 17, 18, 19
MAV_CMD_NAV_SPLINE_WAYPOINT, MAV_CMD_NAV_DELAY = 82, 93
MAV_CMD_CONDITION_DELAY, MAV_CMD_CONDITION_DISTANCE, MAV_CMD_CONDITION_YAW = 112, 114, 115
MAV_CMD_DO_JUMP, MAV_CMD_DO_SET_SERVO, MAV_CMD_DO_LAND_START = 177, 183, 189
MAV_CMD_DO_SET_ROI_LOCATION, MAV_CMD_DO_SET_ROI, MAV_CMD_IMAGE_START_CAPTURE = 195, 201, 2000

#: mission type -> the MAV_CMDs this vehicle stores (ArduCopter's mission command list)
SUPPORTED: dict[int, frozenset[int]] = {
    MISSION: frozenset({I.MAV_CMD_NAV_WAYPOINT, I.MAV_CMD_NAV_TAKEOFF, I.MAV_CMD_NAV_LAND,
                        I.MAV_CMD_NAV_RETURN_TO_LAUNCH, I.MAV_CMD_DO_CHANGE_SPEED, I.MAV_CMD_DO_DIGICAM_CONTROL,
                        I.MAV_CMD_DO_SET_CAM_TRIGG_DIST, MAV_CMD_CONDITION_YAW,
                        MAV_CMD_NAV_LOITER_UNLIM, MAV_CMD_NAV_LOITER_TURNS, MAV_CMD_NAV_LOITER_TIME,
                        MAV_CMD_NAV_SPLINE_WAYPOINT, MAV_CMD_NAV_DELAY, MAV_CMD_CONDITION_DELAY,
                        MAV_CMD_CONDITION_DISTANCE, MAV_CMD_DO_JUMP, MAV_CMD_DO_SET_SERVO, MAV_CMD_DO_LAND_START,
                        MAV_CMD_DO_SET_ROI_LOCATION, MAV_CMD_DO_SET_ROI, MAV_CMD_IMAGE_START_CAPTURE}),
    FENCE: frozenset({I.MAV_CMD_NAV_FENCE_RETURN_POINT, I.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                      I.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, I.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
                      I.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION}),
    RALLY: frozenset({I.MAV_CMD_NAV_RALLY_POINT}),
}
#: commands whose x/y/z are a position
_POSITIONED = {I.MAV_CMD_NAV_WAYPOINT, I.MAV_CMD_NAV_TAKEOFF, I.MAV_CMD_NAV_LAND, MAV_CMD_NAV_LOITER_UNLIM,
               MAV_CMD_NAV_LOITER_TURNS, MAV_CMD_NAV_LOITER_TIME, MAV_CMD_NAV_SPLINE_WAYPOINT,
               *SUPPORTED[FENCE], *SUPPORTED[RALLY]}
#: NAV items whose param4 (yaw) may be NaN ("keep the current heading")
_NAN_YAW = {I.MAV_CMD_NAV_TAKEOFF, I.MAV_CMD_NAV_LAND, I.MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_SPLINE_WAYPOINT,
            MAV_CMD_NAV_LOITER_UNLIM, MAV_CMD_NAV_LOITER_TIME, MAV_CMD_NAV_LOITER_TURNS}


@dataclass(frozen=True)
class PlanItem:
    """One stored item (MISSION_ITEM_INT's fields; x, y are degrees × 1e7 in global frames)."""

    seq: int
    frame: int
    command: int
    current: int = 0
    autocontinue: int = 1
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0
    y: int = 0
    z: float = 0.0
    mission_type: int = MISSION

    @property
    def params(self) -> tuple[float, float, float, float, float, float, float]:
        """param1..param7 as a WPL line has them (x, y in degrees for global frames)."""
        if is_global(self.frame, self.command):
            return (self.param1, self.param2, self.param3, self.param4, self.x / 1e7, self.y / 1e7, self.z)
        return (self.param1, self.param2, self.param3, self.param4, float(self.x), float(self.y), self.z)

    def fields(self) -> dict:
        return dict(seq=self.seq, frame=self.frame, command=self.command, current=self.current,
                    autocontinue=self.autocontinue, param1=self.param1, param2=self.param2, param3=self.param3,
                    param4=self.param4, x=self.x, y=self.y, z=self.z, mission_type=self.mission_type)


def is_global(frame: int, command: int) -> bool:
    """x, y are latitude, longitude: a global frame, or MAV_FRAME_MISSION for a positioned command (ArduPilot
    reads MAV_FRAME_MISSION as MAV_FRAME_GLOBAL there; elsewhere x, y are plain params 5 and 6)."""
    return frame in GLOBAL_FRAMES or (frame == MAV_FRAME_MISSION and command in _POSITIONED)


def item_from_message(msg: object, int_msg: bool) -> PlanItem:
    """A PlanItem from a MISSION_ITEM_INT (``int_msg``) or MISSION_ITEM (float lat/lon) message."""
    g = lambda k, d=0: getattr(msg, k, d)  # noqa: E731
    frame = int(g("frame"))
    x, y = g("x"), g("y")
    if not int_msg:
        if is_global(frame, int(g("command"))):
            x = round(float(x) * 1e7) if math.isfinite(x) else 0
            y = round(float(y) * 1e7) if math.isfinite(y) else 0
        else:
            x = round(float(x)) if math.isfinite(x) else 0
            y = round(float(y)) if math.isfinite(y) else 0
    return PlanItem(int(g("seq")), frame, int(g("command")), int(g("current")), int(g("autocontinue", 1)),
                    float(g("param1")), float(g("param2")), float(g("param3")), float(g("param4")),
                    int(x), int(y), float(g("z")), int(g("mission_type")))


def check_item(it: PlanItem) -> int:
    """MAV_MISSION_ACCEPTED, or the MAV_MISSION_RESULT that refuses the item."""
    if it.command not in SUPPORTED.get(it.mission_type, ()):
        return MAV_MISSION_UNSUPPORTED
    if it.command == I.MAV_CMD_NAV_WAYPOINT and not math.isfinite(it.param1):
        return MAV_MISSION_INVALID_PARAM1  # the hold time: ArduCopter refuses NaN
    if not all(math.isfinite(v) for v in (it.param1, it.param2, it.param3, it.param4)) and it.command not in _NAN_YAW:
        return MAV_MISSION_INVALID  # NAV items may carry NaN yaw ("keep the current heading")
    if it.command in _POSITIONED:
        if not is_global(it.frame, it.command):
            return MAV_MISSION_UNSUPPORTED_FRAME
        if not math.isfinite(it.z) or abs(it.x) > 900_000_000 or abs(it.y) > 1_800_000_000:
            return MAV_MISSION_INVALID
    return MAV_MISSION_ACCEPTED


@dataclass
class _Upload:
    src: tuple[int, int]
    mission_type: int
    count: int
    use_int: bool
    items: list[PlanItem]
    last_rx: float
    tries: int = 0


def _as_downloaded(it: PlanItem) -> PlanItem:
    """An item as ArduCopter sends it back: NaN params as 0.0, RTL (stored without a location) in frame 0."""
    p = [v if math.isfinite(v) else 0.0 for v in (it.param1, it.param2, it.param3, it.param4)]
    frame = 0 if it.command == I.MAV_CMD_NAV_RETURN_TO_LAUNCH else it.frame
    return replace(it, frame=frame, param1=p[0], param2=p[1], param3=p[2], param4=p[3])


class MissionServer:
    """The vehicle's plan stores and the transfer state machine (see the module docstring).

    ``home`` is a callable returning the home item (seq 0 of the mission on download).
    """

    def __init__(self, home: callable[[], PlanItem] | None = None, item_timeout_s: float = 1.0, retries: int = 5,
                 legacy_request: bool = False):
        self.stores: dict[int, list[PlanItem]] = {MISSION: [], FENCE: [], RALLY: []}
        self.legacy_request = bool(legacy_request)
        self.home = home
        self.item_timeout_s = float(item_timeout_s)
        self.retries = int(retries)
        self._up: _Upload | None = None
        self.rejected = 0

    @staticmethod
    def _ack(src: tuple[int, int], result: int, mission_type: int) -> Out:
        return ("mission_ack", dict(target_system=src[0], target_component=src[1], type=result,
                                    mission_type=mission_type))

    def _request(self, up: _Upload) -> Out:
        name = "mission_request_int" if up.use_int and not self.legacy_request else "mission_request"
        return (name, dict(target_system=up.src[0], target_component=up.src[1], seq=len(up.items),
                           mission_type=up.mission_type))

    @property
    def busy(self) -> bool:
        return self._up is not None

    def count(self, src: tuple[int, int], mission_type: int, count: int, now: float) -> list[Out]:
        """MISSION_COUNT from ``src``: open an upload (or clear for 0)."""
        if mission_type not in self.stores:
            self.rejected += 1
            return [self._ack(src, MAV_MISSION_UNSUPPORTED, mission_type)]
        if self._up is not None and self._up.src != src:
            self.rejected += 1
            return [self._ack(src, MAV_MISSION_DENIED, mission_type)]
        if count <= 0:
            self._up = None
            self.stores[mission_type] = []
            return [self._ack(src, MAV_MISSION_ACCEPTED, mission_type)]
        if count > 10_000:
            self.rejected += 1
            return [self._ack(src, MAV_MISSION_ERROR, mission_type)]  # ArduPilot: MAV_MISSION_NO_SPACE-like
        self._up = _Upload(src, mission_type, int(count), True, [], now)
        return [self._request(self._up)]

    def item(self, src: tuple[int, int], it: PlanItem, int_msg: bool, now: float) -> list[Out]:
        """MISSION_ITEM_INT / MISSION_ITEM from ``src`` during an upload."""
        up = self._up
        if up is None or up.src != src or it.mission_type != up.mission_type:
            self.rejected += 1
            return []  # not uploading to this sender: ArduPilot ignores it
        if it.seq != len(up.items):
            up.use_int = int_msg
            return [self._request(up)]  # duplicate or out of order: ask again for the one we need
        it = replace(it, frame=_INT_FRAMES.get(it.frame, it.frame))
        result = check_item(it)
        if result != MAV_MISSION_ACCEPTED:
            self._up = None
            self.rejected += 1
            return [self._ack(src, result, up.mission_type)]
        up.items.append(it)
        up.use_int = int_msg
        up.last_rx, up.tries = now, 0
        if len(up.items) < up.count:
            return [self._request(up)]
        self.stores[up.mission_type] = up.items
        self._up = None
        return [self._ack(src, MAV_MISSION_ACCEPTED, up.mission_type)]

    def tick(self, now: float) -> list[Out]:
        """Re-request a missing item after ``item_timeout_s``; cancel after ``retries`` re-requests."""
        up = self._up
        if up is None or now - up.last_rx < self.item_timeout_s:
            return []
        up.last_rx = now
        up.tries += 1
        if up.tries > self.retries:
            self._up = None
            return [self._ack(up.src, MAV_MISSION_OPERATION_CANCELLED, up.mission_type)]
        return [self._request(up)]

    def _listed(self, mission_type: int) -> list[PlanItem]:
        items = self.stores[mission_type]
        if mission_type == MISSION and self.home is not None:
            home = replace(self.home(), seq=0)
            return [home, *items[1:]] if items else [home]
        return items

    def request_list(self, src: tuple[int, int], mission_type: int) -> list[Out]:
        """MISSION_REQUEST_LIST: MISSION_COUNT."""
        if mission_type not in self.stores:
            return [self._ack(src, MAV_MISSION_UNSUPPORTED, mission_type)]
        return [("mission_count", dict(target_system=src[0], target_component=src[1],
                                       count=len(self._listed(mission_type)), mission_type=mission_type))]

    def request(self, src: tuple[int, int], mission_type: int, seq: int, int_msg: bool) -> list[Out]:
        """MISSION_REQUEST_INT / MISSION_REQUEST: the item (MISSION_ITEM_INT / MISSION_ITEM)."""
        if mission_type not in self.stores:
            return [self._ack(src, MAV_MISSION_UNSUPPORTED, mission_type)]
        items = self._listed(mission_type)
        if not 0 <= seq < len(items):
            return [self._ack(src, MAV_MISSION_INVALID_SEQUENCE, mission_type)]
        f = _as_downloaded(items[seq]).fields()
        f["mission_type"] = mission_type
        if not int_msg:
            p = items[seq].params
            f["x"], f["y"] = p[4], p[5]
        return [("mission_item_int" if int_msg else "mission_item",
                 dict(target_system=src[0], target_component=src[1], **f))]

    def clear(self, src: tuple[int, int], mission_type: int) -> list[Out]:
        """MISSION_CLEAR_ALL."""
        if mission_type == 255:  # MAV_MISSION_TYPE_ALL
            for k in self.stores:
                self.stores[k] = []
            return [self._ack(src, MAV_MISSION_ACCEPTED, mission_type)]
        if mission_type not in self.stores:
            return [self._ack(src, MAV_MISSION_UNSUPPORTED, mission_type)]
        self.stores[mission_type] = []
        return [self._ack(src, MAV_MISSION_ACCEPTED, mission_type)]

    def mission(self) -> list[PlanItem]:
        """The stored mission (item 0 = home)."""
        return list(self.stores[MISSION])
