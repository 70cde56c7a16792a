"""Command validation on board: nothing invalid reaches the vehicle.

Design notes: docs/edge.md (edge/geometry/validate.py).
"""

from __future__ import annotations

import math

from protocol.messages import Box, Message, SetFormation, Takeoff, Trajectory, UploadTrajectory

#: slack on speeds implied by consecutive waypoints (interpolation overshoot, rounding)
SPEED_SLACK = 1.25
#: largest formation offset accepted, m
MAX_OFFSET_M = 50.0


def trajectory_problem(traj: Trajectory, geofence: Box | None, max_speed: float) -> str:
    """Why a trajectory must be refused, or ``""``."""
    wps = traj.waypoints
    for i, w in enumerate(wps):
        if geofence is not None and not geofence.contains(w.pos):
            return f"waypoint {i} at ({w.pos[0]:.1f}, {w.pos[1]:.1f}, {w.pos[2]:.1f}) is outside the geofence"
        if w.speed > max_speed:
            return f"waypoint {i} speed {w.speed:.1f} m/s exceeds {max_speed:.1f} m/s"
    for i, (a, b) in enumerate(zip(wps, wps[1:])):
        v = math.dist(a.pos, b.pos) / (b.t - a.t)
        if v > max_speed * SPEED_SLACK:
            return f"segment {i}->{i + 1} needs {v:.1f} m/s, more than {max_speed:.1f} m/s"
    return ""


def narrowed_fence(current: Box | None, offered: Box) -> Box:
    """The board's fence after a signed upload offers ``offered``: never wider than ``current``.

    The fence the board was configured with (``--geofence``) or first given by the ground station
    is a ceiling: a later fence can only narrow it (the intersection of the two boxes). ValueError
    when the two do not overlap (nothing could be flown in both).
    """
    if current is None:
        return offered
    lo = tuple(max(a, b) for a, b in zip(current.lo, offered.lo))
    hi = tuple(min(a, b) for a, b in zip(current.hi, offered.hi))
    if any(h <= l for l, h in zip(lo, hi)):
        raise ValueError("the uploaded geofence does not overlap the board's geofence "
                         f"{tuple(current.lo)}..{tuple(current.hi)}")
    return Box(lo=lo, hi=hi)


def validate_command(cmd: Message, uav: int, geofence: Box | None, max_speed: float) -> str:
    """Why ``cmd`` must be refused by UAV ``uav``, or ``""`` when it may reach the vehicle."""
    target = getattr(cmd, "uav", None)
    if target != uav:
        return f"command addressed to UAV {target}, this is UAV {uav}"
    if isinstance(cmd, UploadTrajectory):
        if cmd.trajectory.uav != uav:
            return f"trajectory is for UAV {cmd.trajectory.uav}"
        # inside the board's fence and inside the one it comes with (neither may widen the other)
        why = trajectory_problem(cmd.trajectory, geofence, max_speed)
        if not why and cmd.geofence is not None:
            why = trajectory_problem(cmd.trajectory, cmd.geofence, max_speed)
        return why
    if isinstance(cmd, Takeoff) and geofence is not None:
        if cmd.altitude > geofence.hi[2] - geofence.lo[2]:
            return f"takeoff altitude {cmd.altitude:.1f} m is above the geofence"
    if isinstance(cmd, SetFormation):
        if uav not in cmd.offsets:
            return f"formation has no offset for UAV {uav}"
        for k, v in cmd.offsets.items():
            if math.hypot(*v) > MAX_OFFSET_M:
                return f"offset of UAV {k} is farther than {MAX_OFFSET_M:.0f} m"
    return ""
