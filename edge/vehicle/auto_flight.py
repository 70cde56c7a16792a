"""Flying the formation trajectory the paper's way: a waypoint mission in AUTO, kept in time by speed.

Design notes: docs/hardware-mavlink.md (edge/vehicle/auto_flight.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pymap3d

from edge.geometry import ardupilot_items as AI
from edge.geometry.waypoint_mission import mission_items
from edge.vehicle.apm.missions import PlanItem
from protocol.messages import Trajectory

__all__ = ["AutoMissionPlan", "autopilot_mission", "decimate", "resume_item", "speed_correction"]

Vec3 = tuple[float, float, float]
_GLOBAL = (AI.MAV_FRAME_GLOBAL, AI.MAV_FRAME_GLOBAL_RELATIVE_ALT)


@dataclass(frozen=True)
class AutoMissionPlan:
    """The items to upload and, per trajectory waypoint, the sequence number of its NAV_WAYPOINT."""

    items: tuple[PlanItem, ...]
    waypoint_seq: tuple[int, ...]  # per trajectory waypoint: its NAV_WAYPOINT, or the last kept one's before it
    capture_seq: dict[int, int]  # capture id -> seq of its DO_DIGICAM_CONTROL


def _off_segment(p: Vec3, a: Vec3, b: Vec3) -> float:
    """Distance of point p from segment ab, m."""
    ab = [y - x for x, y in zip(a, b)]
    n2 = sum(v * v for v in ab)
    if n2 < 1e-12:
        return math.dist(p, a)
    u = max(0.0, min(1.0, sum((q - x) * v for q, x, v in zip(p, a, ab)) / n2))
    return math.dist(p, [x + u * v for x, v in zip(a, ab)])


def decimate(traj: Trajectory, tolerance_m: float = 0.3, speed_tol: float = 0.1,
             max_leg_s: float = 8.0, min_leg_s: float = 2.0) -> list[int]:
    """Indices of the trajectory waypoints a mission keeps (see the module docstring); sorted, first and last in."""
    if not (0 < tolerance_m <= 10 and 0 <= speed_tol <= 1 and 0 <= min_leg_s < max_leg_s <= 600):
        raise ValueError("tolerance_m in (0, 10], speed_tol in [0, 1], 0 <= min_leg_s < max_leg_s <= 600")
    w = traj.waypoints
    n = len(w)
    leg_len = [math.dist(w[k].pos, w[k + 1].pos) for k in range(n - 1)]
    leg_v = [leg_len[k] / (w[k + 1].t - w[k].t) for k in range(n - 1)]
    kept = [0]
    k = 0
    while k < n - 1:
        j = k + 1
        while j < n - 1 and w[j].capture_id is None and leg_len[j - 1] >= 0.01 and leg_len[j] >= 0.01:
            nxt = j + 1
            if w[j].t - w[k].t < min_leg_s:
                j = nxt  # too short a leg for ArduCopter to fly at speed: drop j whatever the shape
                continue
            v = sum(leg_len[k:nxt]) / (w[nxt].t - w[k].t)
            if (w[nxt].t - w[k].t > max_leg_s or any(abs(leg_v[m] - v) > speed_tol * max(v, 1e-6)
                                                     for m in range(k, nxt))
                    or any(_off_segment(w[m].pos, w[k].pos, w[nxt].pos) > tolerance_m for m in range(k + 1, nxt))):
                break
            j = nxt
        kept.append(j)
        k = j
    return kept


def autopilot_mission(traj: Trajectory, home_enu: Vec3, home_lla: Vec3) -> AutoMissionPlan:
    """The trajectory as mission items about the autopilot's home (see the module docstring).

    ``home_enu``: the launch point in the mission's ENU frame, m; ``home_lla``: the autopilot's
    HOME_POSITION (degrees, degrees, m).
    """
    lat0, lon0, h0 = (float(v) for v in home_lla)
    if not (abs(lat0) <= 90 and abs(lon0) <= 180 and math.isfinite(h0)):
        raise ValueError(f"home position {home_lla!r} is not a geodetic point")
    hx, hy, hz = home_enu
    # the mission frame's origin as the autopilot sees it: home minus home's ENU position
    origin = pymap3d.enu2geodetic(-hx, -hy, -hz, lat0, lon0, h0)
    out: list[PlanItem] = []
    wps: list[int] = []
    captures: dict[int, int] = {}
    keep = decimate(traj)
    src = mission_items(Trajectory(uav=traj.uav, waypoints=[traj.waypoints[i] for i in keep]), origin)
    if src and src[-1].command == AI.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        src = src[:-1]
    for it in src:
        p = it.params
        seq = len(out)
        if it.frame in _GLOBAL:
            z = p[6] - hz if it.frame == AI.MAV_FRAME_GLOBAL_RELATIVE_ALT else p[6]  # above home
            x, y = round(p[4] * 1e7), round(p[5] * 1e7)
        else:
            x, y, z = int(p[4]), int(p[5]), p[6]
        out.append(PlanItem(seq=seq, frame=it.frame, command=it.command, param1=p[0], param2=p[1], param3=p[2],
                            param4=p[3], x=x, y=y, z=z))
        if seq >= 2 and it.command == AI.MAV_CMD_NAV_WAYPOINT:
            wps.append(seq)
        elif it.command == AI.MAV_CMD_DO_DIGICAM_CONTROL:
            cid = AI.capture_id(p)
            if cid is not None:
                captures[cid] = seq
    if len(wps) != len(keep):
        raise ValueError(f"mission has {len(wps)} waypoints for {len(keep)} kept of the trajectory")
    per_wp: list[int] = []
    m = 0
    for i in range(len(traj.waypoints)):
        while m + 1 < len(keep) and keep[m + 1] <= i:
            m += 1
        per_wp.append(wps[m])
    return AutoMissionPlan(tuple(out), tuple(per_wp), captures)


def resume_item(plan: AutoMissionPlan, last_waypoint: int) -> int:
    """The item AUTO continues from once waypoint ``last_waypoint`` (0-based, −1: none) is passed."""
    k = max(0, min(int(last_waypoint), len(plan.waypoint_seq) - 1))
    return min(plan.waypoint_seq[k] + 1, len(plan.items) - 1)


def speed_correction(pos: Vec3, ref: Vec3, ref_vel: Vec3, gain: float = 0.6, min_speed: float = 0.2,
                     max_gain: float = 2.0) -> float | None:
    """Ground speed that closes the along-track error to the reference (None: the reference rests).

    ``v = |v_d| − gain · (P − P_d)·v̂_d``, bounded to ``[min_speed, max_gain · |v_d| + 1]`` m/s.
    """
    vd = math.sqrt(sum(v * v for v in ref_vel))
    if not math.isfinite(vd) or vd < 0.05:
        return None
    along = sum((p - r) * v for p, r, v in zip(pos, ref, ref_vel)) / vd
    if not math.isfinite(along):
        return None
    return max(min_speed, min(max_gain * vd + 1.0, vd - gain * along))
