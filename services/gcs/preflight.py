"""Pre-flight check of a mission plan: does every UAV's trajectory fit the scenario's box?

The boards refuse a trajectory that leaves the geofence (:func:`edge.validate.trajectory_problem`),
but one by one during the upload: with a fleet too long for the box (issue 18: 24 UAVs in one
formation span ±18 m along the track, the monorail start is 8 m from the box's edge) UAV 23's
upload was refused after 22 UAVs had theirs. This check runs the boards' own geofence test on
the whole plan before anything is uploaded, and says why the fleet does not fit.

Pure: no bus code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from edge.validate import trajectory_problem
from protocol.messages import Box, MissionPlan


def along_track_span(offsets: Sequence[Sequence[float]]) -> tuple[float, float]:
    """The formation's extent along the direction of travel, (behind, ahead) of the centroid, m (P9)."""
    xs = [float(o[0]) for o in offsets] or [0.0]
    return -min(0.0, min(xs)), max(0.0, max(xs))


def margin_to_box(point: Sequence[float], box: Box) -> float:
    """Horizontal distance from ``point`` to the nearest side of ``box``, m (negative outside)."""
    x, y = float(point[0]), float(point[1])
    return min(x - box.lo[0], box.hi[0] - x, y - box.lo[1], box.hi[1] - y)


def plan_problem(plan: MissionPlan, offsets: Sequence[Sequence[float]] | None = None) -> str:
    """Why the plan cannot be flown inside its geofence, or ``""``.

    Every trajectory is checked as the boards check it (geofence only: the speeds are the
    boards' own business); the reason names the first offending UAV and waypoint and, with
    the formation ``offsets``, the fleet's along-track extent against the room the start and
    goal leave.
    """
    bad = []
    for traj in plan.trajectories:
        why = trajectory_problem(traj, plan.geofence, math.inf)
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
                 f"its centroid along the track, the start is {margin_to_box(start, plan.geofence):.1f} m and the "
                 f"goal {margin_to_box(goal, plan.geofence):.1f} m from the box's side; fly fewer UAVs or move "
                 "the start and goal inward")
    return text


#: the slowest level transit to the first waypoint assumed for a board, m/s (the simulated vehicle
#: flies it at 4 m/s: ``edge.vehicle.sim.SimParams.transit_speed``)
TRANSIT_SPEED_MS = 3.0


def transit_margin_s(positions: dict[int, Sequence[float]], plan: MissionPlan, speed: float = 1.0,
                     transit_speed: float = TRANSIT_SPEED_MS) -> float:
    """Wall seconds the farthest UAV needs from where it holds to its trajectory's first waypoint.

    The common start time must leave it that long (issue 18): a UAV stacked above another
    launches beside it (:func:`edge.formation.home_offsets`) and flies level to its slot once
    started; arriving after the start time it would begin its trajectory late, and formation
    keeping would pull its formation back while the formations around it fly on. ``speed`` is
    the mission clock's speed factor (simulated seconds per wall second).
    """
    if not (math.isfinite(speed) and speed > 0 and math.isfinite(transit_speed) and transit_speed > 0):
        raise ValueError("speed and transit_speed must be finite and > 0")
    far = 0.0
    for traj in plan.trajectories:
        p = positions.get(traj.uav)
        if p is not None and traj.waypoints:
            far = max(far, math.dist(tuple(p), traj.waypoints[0].pos))
    return far / transit_speed / speed
