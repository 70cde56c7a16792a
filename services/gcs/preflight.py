"""Pre-flight check of a mission plan: does every UAV's trajectory fit the scenario's box?

Design notes: docs/ground-station.md (services/gcs/preflight.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from edge.geometry.validate import trajectory_problem
from protocol.messages import Box, MissionPlan
from protocol.scenario import Scenario

#: the longest step between two points checked on a trajectory's segment against the obstacles, m
SEGMENT_STEP_M = 0.25
#: geodetic origin tolerance: degrees (about 1 cm), metres
ORIGIN_TOL_DEG, ORIGIN_TOL_M = 1e-7, 0.01


def scenario_box(scenario: Scenario) -> Box:
    """The scenario's operation box as the wire's :class:`Box`: the only geofence the edges get."""
    return Box(lo=scenario.box.lo, hi=scenario.box.hi)


def _fmt(p: Sequence[float]) -> str:
    return f"({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f})"


def obstacle_hit(p: Sequence[float], scenario: Scenario) -> int | None:
    """Index of the scenario's obstacle (vertical cylinder from z = 0) that contains point ``p``, or None."""
    for i, c in enumerate(scenario.obstacles):
        if p[2] < c.height and math.hypot(p[0] - c.centre[0], p[1] - c.centre[1]) < c.radius:
            return i
    return None


def _segment_hit(a: Sequence[float], b: Sequence[float], scenario: Scenario) -> tuple[int, tuple] | None:
    """(obstacle index, first point inside it) on the straight segment a-b, or None."""
    if not scenario.obstacles:
        return None
    pa, pb = np.asarray(a, float), np.asarray(b, float)
    n = max(1, int(math.ceil(float(np.linalg.norm(pb - pa)) / SEGMENT_STEP_M)))
    for k in range(1, n):
        q = tuple(pa + (pb - pa) * (k / n))
        i = obstacle_hit(q, scenario)
        if i is not None:
            return i, q
    return None


def scenario_problem(plan: MissionPlan, scenario: Scenario, uavs: Sequence[int] | None = None) -> str:
    """Why ``plan`` leaves the operator's ``scenario`` (naming the UAV and the waypoint), or ``""``.

    Checked, in this order: the plan's origin is the scenario's; with ``uavs``, one trajectory per UAV
    and none for another; every waypoint inside the box and outside every obstacle, and every straight
    segment between two waypoints clear of the obstacles (the box is convex: its waypoints inside, a
    segment is too); the centroid path inside the box; the plan's geofence within the box; every capture point of a UAV of the plan, inside the box, outside the obstacles and, with
    a surface, in front of it looking at it (the normal (p1 - p0) x (p3 - p0) of
    :class:`protocol.scenario.Surface`).
    """
    box = scenario_box(scenario)
    o = scenario.origin
    if (abs(plan.origin[0] - o.lat) > ORIGIN_TOL_DEG or abs(plan.origin[1] - o.lon) > ORIGIN_TOL_DEG
            or abs(plan.origin[2] - o.alt) > ORIGIN_TOL_M):
        return f"the plan's origin {plan.origin} is not the scenario's ({o.lat}, {o.lon}, {o.alt})"
    flown = [t.uav for t in plan.trajectories]
    if len(set(flown)) != len(flown):
        return f"the plan has more than one trajectory for UAV(s) {sorted({u for u in flown if flown.count(u) > 1})}"
    if uavs is not None:
        extra = sorted(set(flown) - set(uavs))
        if extra:
            return f"the plan has trajectories for UAV(s) {extra}, not in the mission"
    for traj in plan.trajectories:
        wps = traj.waypoints
        for i, w in enumerate(wps):
            if not box.contains(w.pos):
                return f"UAV {traj.uav} waypoint {i} at {_fmt(w.pos)} is outside the scenario's box"
            k = obstacle_hit(w.pos, scenario)
            if k is not None:
                return f"UAV {traj.uav} waypoint {i} at {_fmt(w.pos)} is inside obstacle {k}"
        for i, (a, b) in enumerate(zip(wps, wps[1:])):
            hit = _segment_hit(a.pos, b.pos, scenario)
            if hit is not None:
                return f"UAV {traj.uav} segment from waypoint {i} to {i + 1} passes through obstacle {hit[0]} at {_fmt(hit[1])}"
    for i, p in enumerate(plan.centroid_path):
        if not box.contains(p):
            return f"centroid path point {i} at {_fmt(p)} is outside the scenario's box"
    if not (box.contains(plan.geofence.lo) and box.contains(plan.geofence.hi)):
        return (f"the plan's geofence {_fmt(plan.geofence.lo)}..{_fmt(plan.geofence.hi)} reaches outside the "
                f"scenario's box {_fmt(box.lo)}..{_fmt(box.hi)}")
    frame = scenario.surface.frame if scenario.surface is not None else None
    for c in plan.captures:
        if c.uav not in flown:
            return f"capture point {c.capture_id} is for UAV {c.uav}, which has no trajectory"
        if not box.contains(c.pos):
            return f"UAV {c.uav} capture point {c.capture_id} at {_fmt(c.pos)} is outside the scenario's box"
        k = obstacle_hit(c.pos, scenario)
        if k is not None:
            return f"UAV {c.uav} capture point {c.capture_id} at {_fmt(c.pos)} is inside obstacle {k}"
        if frame is not None:
            p0, _, n = frame
            if float(np.dot(np.subtract(c.pos, p0), n)) <= 0.0 or float(np.dot(c.look, n)) >= 0.0:
                return (f"UAV {c.uav} capture point {c.capture_id} at {_fmt(c.pos)} does not face the scenario's "
                        "surface from its inspection side")
    return ""


def along_track_span(offsets: Sequence[Sequence[float]]) -> tuple[float, float]:
    """The formation's extent along the direction of travel, (behind, ahead) of the centroid, m (P9)."""
    xs = [float(o[0]) for o in offsets] or [0.0]
    return -min(0.0, min(xs)), max(0.0, max(xs))


def margin_to_box(point: Sequence[float], box: Box) -> float:
    """Horizontal distance from ``point`` to the nearest side of ``box``, m (negative outside)."""
    x, y = float(point[0]), float(point[1])
    return min(x - box.lo[0], box.hi[0] - x, y - box.lo[1], box.hi[1] - y)


def plan_problem(plan: MissionPlan, offsets: Sequence[Sequence[float]] | None = None, fence: Box | None = None) -> str:
    """Why the plan cannot be flown inside ``fence`` (the scenario's box; the plan's own geofence
    only when none is given), or ``""``.

    Every trajectory is checked as the boards check it (geofence only: the speeds are the
    boards' own business); the reason names the first offending UAV and waypoint and, with
    the formation ``offsets``, the fleet's along-track extent against the room the start and
    goal leave.
    """
    fence = fence if fence is not None else plan.geofence
    bad = []
    for traj in plan.trajectories:
        why = trajectory_problem(traj, fence, math.inf)
        if why:
            bad.append((traj.uav, why))
    if not bad:
        return ""
    uav, why = bad[0]
    text = (f"{len(bad)} of {len(plan.trajectories)} UAVs' trajectories leave the scenario's box "
            f"(first: UAV {uav}, {why})")
    if offsets is not None and len(plan.centroid_path) >= 2:
        behind, ahead = along_track_span(offsets)
        start, goal = plan.centroid_path[0], plan.centroid_path[-1]
        text += (f": the formation of {len(offsets)} UAVs spans {behind:.0f} m behind and {ahead:.0f} m ahead of "
                 f"its centroid along the track, the start is {margin_to_box(start, fence):.1f} m and the "
                 f"goal {margin_to_box(goal, fence):.1f} m from the box's side; fly fewer UAVs or move "
                 "the start and goal inward")
    return text


#: the slowest level transit to the first waypoint assumed for a board, m/s (the simulated vehicle
#: flies it at 4 m/s: ``edge.vehicle.sim.SimParams.transit_speed``)
TRANSIT_SPEED_MS = 3.0


def transit_margin_s(positions: dict[int, Sequence[float]], plan: MissionPlan, speed: float = 1.0,
                     transit_speed: float = TRANSIT_SPEED_MS) -> float:
    """Wall seconds the farthest UAV needs from where it holds to its trajectory's first waypoint; ``speed`` is the
    mission clock's speed factor (simulated seconds per wall second)."""
    if not (math.isfinite(speed) and speed > 0 and math.isfinite(transit_speed) and transit_speed > 0):
        raise ValueError("speed and transit_speed must be finite and > 0")
    far = 0.0
    for traj in plan.trajectories:
        p = positions.get(traj.uav)
        if p is not None and traj.waypoints:
            far = max(far, math.dist(tuple(p), traj.waypoints[0].pos))
    return far / transit_speed / speed
