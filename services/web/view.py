"""The live fleet view: what the web page shows, built from the fleet's messages. Pure, no I/O.

Design notes: docs/operator-view.md (services/web/view.py).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from typing import Any

from edge.geometry.formation import DEFAULT_OFFSETS, ShapeErrorMeter, tracking_error
from protocol.checks import xyz
from protocol.keys import DEFAULT_FLEET, REPLAY_SUFFIX
from protocol.messages import DefectReport, Event, MissionPlan, VehicleState
from protocol.scenario import Scenario

TRAIL_STEP_M = 0.5
TRAIL_POINTS = 2000
EVENTS = 200
DEFECTS = 5000
SENT_TRAIL = 400  # newest trail points per snapshot
SENT_DEFECTS = 500  # newest defects per snapshot (the count is of all)
SENT_EVENTS = 100  # newest timeline entries per snapshot
REPLAY_FLEET_SUFFIX = REPLAY_SUFFIX  # the fleet name ``skynet replay`` plays a recording under, beside the live one
SOURCE_WINDOW_S = 5.0  # data heard within this long decides the page's "live" / "replay" label
RATE_WINDOW_S = 2.0
STATE_HZ = 20.0  # the edges' telemetry rate (edge.config)


def _round(x: float | None, nd: int = 3) -> float | None:
    return None if x is None else round(x, nd)


def _r(v, nd: int = 2):
    return [round(float(x), nd) for x in v]


class _Uav:
    def __init__(self) -> None:
        self.state: VehicleState | None = None
        self.rx = 0.0
        self.arrivals: deque[float] = deque()
        self.trail: deque[list[float]] = deque(maxlen=TRAIL_POINTS)
        self.preview_seq = 0
        self.preview: bytes | None = None
        self.captures = 0


class FleetView:
    """Thread-safe: the bus callbacks feed it, the web server's task reads it."""

    def __init__(self, scenario: Scenario | None = None, fleet: str = DEFAULT_FLEET, clock=time.time):
        self.fleet, self.clock = fleet, clock
        self.scenario = scenario
        self.plan: MissionPlan | None = None
        self._uavs: dict[int, _Uav] = {}
        self._events: deque[dict] = deque(maxlen=EVENTS)
        self._defects: deque[dict] = deque(maxlen=DEFECTS)
        self.reports = 0
        self.detections = 0  # every placed defect of every report (a crack seen in 3 frames counts 3)
        self.inspection: dict[str, Any] | None = None  # the deduplicated count (set_inspection)
        self.static_version = 0
        self._heard = {"live": -math.inf, "replay": -math.inf}  # when each kind of data was last heard
        self._shape: ShapeErrorMeter | None = None  # the formation error's heading memory
        self._shape_t = -math.inf
        self._lock = threading.Lock()

    def _uav(self, uav: int) -> _Uav:
        if uav not in self._uavs:
            self._uavs[uav] = _Uav()
        return self._uavs[uav]

    # -- inputs (``replayed``: the sample came from ``skynet replay``, services.web.service tells)
    def _hear(self, now: float, replayed: bool) -> None:
        kind = "replay" if replayed or self.fleet.endswith(REPLAY_FLEET_SUFFIX) else "live"
        self._heard[kind] = max(self._heard[kind], now)

    def _note(self, t: float, source: str, kind: str, text: str, level: str = "info") -> None:
        self._events.append({"t": t, "source": source, "kind": kind, "level": level, "text": text})

    def note(self, t: float, source: str, kind: str, text: str, level: str = "info") -> None:
        """A timeline entry from this process (the ground station's phases and warnings)."""
        with self._lock:
            self._note(t, source, kind, text, level)

    def on_state(self, msg: VehicleState, rx: float | None = None, replayed: bool = False) -> None:
        now = self.clock() if rx is None else rx
        with self._lock:
            self._hear(now, replayed)
            u = self._uav(msg.uav)
            if u.state is not None and u.state.mode != msg.mode:  # the UAV's own phases, seen by any page
                self._note(msg.stamp, f"uav/{msg.uav}", "mode", f"{u.state.mode.value} -> {msg.mode.value}")
            if msg.captures > u.captures:
                self._note(msg.stamp, f"uav/{msg.uav}", "capture",
                           f"capture {msg.captures}" if msg.captures == u.captures + 1
                           else f"captures {u.captures + 1}-{msg.captures}")
                u.captures = msg.captures
            u.state, u.rx = msg, now
            u.arrivals.append(now)
            while u.arrivals and u.arrivals[0] < now - RATE_WINDOW_S:
                u.arrivals.popleft()
            p = _r(msg.pos)
            if not u.trail or math.dist(u.trail[-1], p) >= TRAIL_STEP_M:
                u.trail.append(p)

    def on_event(self, msg: Event, replayed: bool = False) -> None:
        with self._lock:
            self._hear(self.clock(), replayed)
            self._note(msg.stamp, msg.source, msg.kind, msg.text, msg.level.value)

    def on_defects(self, msg: DefectReport, replayed: bool = False) -> None:
        with self._lock:
            self._hear(self.clock(), replayed)
            self.reports += 1
            placed = 0
            for d in msg.defects:
                if d.pos is not None:
                    placed += 1
                    self._defects.append({"uav": msg.uav, "capture": msg.capture_id, "pos": _r(d.pos),
                                          "length_m": d.length_m})
            self.detections += placed
            if not msg.ok:
                self._note(msg.stamp_report, f"uav/{msg.uav}", "defect-report",
                           f"capture {msg.capture_id}: no result", "warning")
            elif msg.defects:
                self._note(msg.stamp_report, f"uav/{msg.uav}", "defect-report",
                           f"capture {msg.capture_id}: {len(msg.defects)} detection(s)")

    def set_inspection(self, defects: int, frames: int) -> None:
        """The deduplicated defect count of ``frames`` captures, as the mission report counts it
        (services.inspection: one defect per connected crack on the mosaic; services.web.tally)."""
        with self._lock:
            self.inspection = {"defects": int(defects), "frames": int(frames)}

    def on_preview(self, uav: int, jpeg: bytes) -> None:
        with self._lock:
            u = self._uav(uav)
            u.preview, u.preview_seq = bytes(jpeg), u.preview_seq + 1

    def set_plan(self, plan: MissionPlan) -> None:
        with self._lock:
            self.plan = plan
            self.static_version += 1

    def set_scenario(self, scenario: Scenario) -> None:
        with self._lock:
            self.scenario = scenario
            self.static_version += 1

    def preview(self, uav: int) -> bytes | None:
        with self._lock:
            u = self._uavs.get(uav)
            return None if u is None else u.preview

    def offsets(self) -> dict[int, tuple[float, float, float]]:
        """The formation offsets ΔT_n by UAV (the scenario's, else the default triangle's)."""
        rows = self.scenario.formation.offsets if self.scenario is not None else DEFAULT_OFFSETS
        return {i + 1: xyz(o) for i, o in enumerate(rows)}

    def _formation_error(self) -> float | None:
        """The formation error of the latest states (services.gcs.progress.formation_rms's rule: the UAVs in
        MISSION or HOLD, at the newest state's time)."""
        offsets = self.offsets()
        states = {u: x.state for u, x in self._uavs.items() if x.state is not None}
        ids = [u for u in sorted(states) if u in offsets and states[u].mode.value in ("mission", "hold")]
        if len(ids) < 2:
            return None
        t = max(states[u].t for u in ids)
        if self._shape is None or self._shape.offsets != offsets:
            self._shape, self._shape_t = ShapeErrorMeter(offsets), -math.inf
        if t > self._shape_t:
            self._shape_t = t
            self._shape.add(t, {u: states[u].pos for u in ids})
        return self._shape.latest

    # -- outputs
    def static(self) -> dict[str, Any]:
        with self._lock:
            sc, plan = self.scenario, self.plan
            out: dict[str, Any] = {"type": "static", "version": self.static_version, "fleet": self.fleet}
            if sc is not None:
                doc = sc.model_dump(mode="json")
                out["box"] = doc["box"]
                out["obstacles"] = doc["obstacles"]
                if sc.surface is not None:
                    out["wall"] = doc["surface"]["corners"]
            if plan is not None:
                out["planned"] = {str(t.uav): [_r(w.pos, 1) for w in t.waypoints[:: max(1, len(t.waypoints) // 400)]]
                                  for t in plan.trajectories}
                out["captures"] = len(plan.captures)
            return out

    def snapshot(self) -> dict[str, Any]:
        now = self.clock()
        with self._lock:
            uavs, pos, refs = {}, {}, {}
            for uid, u in sorted(self._uavs.items()):
                s = u.state
                entry: dict[str, Any] = {"preview": u.preview_seq, "trail": list(u.trail)[-SENT_TRAIL:]}
                if s is not None:
                    recent = sum(1 for a in u.arrivals if a >= now - RATE_WINDOW_S)
                    entry.update(pos=_r(s.pos), mode=s.mode.value, battery=round(s.battery, 3),
                                 captures=s.captures, progress=round(s.progress, 3), neighbours=s.neighbours,
                                 age_s=round(max(0.0, now - u.rx), 2), rate_hz=round(recent / RATE_WINDOW_S, 1),
                                 health=round(min(1.0, recent / RATE_WINDOW_S / STATE_HZ), 2))
                    if s.ref is not None and s.mode.value == "mission":
                        pos[uid], refs[uid] = s.pos, s.ref
                uavs[str(uid)] = entry
            live, replay = (now - self._heard[k] <= SOURCE_WINDOW_S for k in ("live", "replay"))
            insp = self.inspection
            return {"type": "snapshot", "t": round(now, 3), "static_version": self.static_version, "uavs": uavs,
                    "formation_error_m": _round(self._formation_error()),
                    "tracking_error_m": _round(tracking_error(pos, refs)),
                    "source": "live+replay" if live and replay else "replay" if replay else "live" if live else None,
                    "defects": list(self._defects)[-SENT_DEFECTS:], "detections": self.detections,
                    "defect_count": None if insp is None else insp["defects"],
                    "inspection": None if insp is None else dict(insp), "reports": self.reports,
                    "events": sorted(list(self._events)[-SENT_EVENTS:], key=lambda e: e["t"])}
