"""Captures where they belong: where each imaged frame was taken, measured against its capture point.

Design notes: docs/report.md (services/gcs/capture_pose.py).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable

from protocol.messages import DefectReport, Trajectory, VehicleState

__all__ = ["CAPTURE_TOLERANCE_M", "MAX_GAP_S", "NEAR_S", "capture_errors", "far_captures", "far_text"]

#: a frame taken farther than this from its capture point is refused, m: above the formation's
#: corrections (P8, at most the edge's 3 m offset bound) plus the tracking lag of a MAVLink vehicle
#: at an accelerated simulation (up to ~3.4 m seen in GUIDED at x8), far below the tens of metres
#: of a mission flown off its clock
CAPTURE_TOLERANCE_M = 5.0
#: states farther apart than this are not interpolated between, s (wall clock)
MAX_GAP_S = 1.0
#: across a gap (or beyond the first or last state), a capture is placed only at a state this close to it, s
NEAR_S = 0.1

Key = tuple[int, int]


def _position_at(stamps: list[float], states: list[VehicleState], t: float) -> tuple[float, ...] | None:
    i = bisect.bisect_left(stamps, t)
    if 0 < i < len(stamps):
        a, b = states[i - 1], states[i]
        span = b.stamp - a.stamp
        if span > MAX_GAP_S:
            near = a if t - a.stamp <= b.stamp - t else b
            return tuple(near.pos) if abs(near.stamp - t) <= NEAR_S else None
        f = (t - a.stamp) / span if span > 0 else 0.0
        return tuple(pa + f * (pb - pa) for pa, pb in zip(a.pos, b.pos))
    near = states[0] if i == 0 else states[-1]
    return tuple(near.pos) if abs(near.stamp - t) <= NEAR_S else None


def capture_errors(trajectories: Iterable[Trajectory], states: Iterable[VehicleState],
                   reports: Iterable[DefectReport]) -> dict[Key, float]:
    """``(uav, capture_id)`` -> distance (m) from where its ``ok`` frame was taken to its capture point
    (planned captures with a placeable frame only)."""
    points = {(t.uav, w.capture_id): w.pos for t in trajectories for w in t.waypoints if w.capture_id is not None}
    by_uav: dict[int, list[VehicleState]] = {}
    for s in states:
        by_uav.setdefault(s.uav, []).append(s)
    tracks = {}
    for u, ss in by_uav.items():
        ss.sort(key=lambda s: s.stamp)
        tracks[u] = ([s.stamp for s in ss], ss)
    out: dict[Key, float] = {}
    for r in reports:
        key = (r.uav, r.capture_id)
        if not r.ok or key not in points or r.uav not in tracks:
            continue
        p = _position_at(*tracks[r.uav], r.stamp_capture)
        if p is not None:
            d = math.dist(p, points[key])
            out[key] = min(d, out.get(key, math.inf))  # a capture re-taken: its best frame
    return out


def far_captures(trajectories: Iterable[Trajectory], states: Iterable[VehicleState], reports: Iterable[DefectReport],
                 tolerance_m: float = CAPTURE_TOLERANCE_M) -> dict[Key, float]:
    """The captures whose frame was taken farther than ``tolerance_m`` from the capture point."""
    return {k: d for k, d in capture_errors(trajectories, states, reports).items() if d > tolerance_m}


def far_text(far: dict[Key, float], tolerance_m: float = CAPTURE_TOLERANCE_M) -> str:
    """The verdict's one line naming them (at most ten)."""
    worst = sorted(far.items(), key=lambda kv: -kv[1])
    names = ", ".join(f"UAV {u} capture {c} at {d:.1f} m" for (u, c), d in worst[:10])
    more = f" and {len(far) - 10} more" if len(far) > 10 else ""
    return (f"{len(far)} capture(s) taken farther than {tolerance_m:g} m from their capture points "
            f"(not imaged where planned): {names}{more}")
