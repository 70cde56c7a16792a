"""One UAV's trajectory as a MAVLink waypoint mission: the item builder that the planner's exports
(:mod:`services.planner.export`: WPL 110, QGC ``.plan``) and the edge's AUTO flight
(:mod:`edge.vehicle.auto_flight`) share.

Design notes: docs/hardware-mavlink.md (edge/geometry/waypoint_mission.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray

from edge.geometry import ardupilot_items as AI
from protocol.messages import Trajectory

__all__ = ["MissionItem", "enu_to_geodetic", "geodetic_to_enu", "mission_items"]

MAV_CMD_NAV_WAYPOINT = AI.MAV_CMD_NAV_WAYPOINT
MAV_CMD_NAV_RETURN_TO_LAUNCH = AI.MAV_CMD_NAV_RETURN_TO_LAUNCH
MAV_CMD_NAV_TAKEOFF = AI.MAV_CMD_NAV_TAKEOFF
MAV_CMD_DO_DIGICAM_CONTROL = AI.MAV_CMD_DO_DIGICAM_CONTROL
MAV_CMD_DO_CHANGE_SPEED = AI.MAV_CMD_DO_CHANGE_SPEED
MAV_CMD_CONDITION_YAW = 115
MAV_FRAME_GLOBAL = AI.MAV_FRAME_GLOBAL
MAV_FRAME_MISSION = AI.MAV_FRAME_MISSION
MAV_FRAME_GLOBAL_RELATIVE_ALT = AI.MAV_FRAME_GLOBAL_RELATIVE_ALT


@dataclass(frozen=True)
class MissionItem:
    """One line of a QGC WPL 110 file."""

    index: int
    current: int
    frame: int
    command: int
    params: tuple[float, float, float, float, float, float, float]
    autocontinue: int = 1


def _origin(origin: ArrayLike) -> tuple[float, float, float]:
    o = np.asarray(origin, float)
    if o.shape != (3,) or not np.all(np.isfinite(o)) or abs(o[0]) > 90 or abs(o[1]) > 180:
        raise ValueError(f"origin must be (lat, lon, alt) in degrees/metres, got {origin!r}")
    return float(o[0]), float(o[1]), float(o[2])


def _triples(a: ArrayLike, name: str) -> NDArray[np.float64]:
    p = np.asarray(a, float)
    if p.shape[-1:] != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be finite with a last axis of 3")
    return p


def enu_to_geodetic(enu: ArrayLike, origin: ArrayLike) -> NDArray[np.float64]:
    """Local ENU metres ``(..., 3)`` to ``(..., 3)`` latitude, longitude (deg), altitude (m)."""
    p = _triples(enu, "enu")
    lat0, lon0, h0 = _origin(origin)
    lat, lon, h = pymap3d.enu2geodetic(p[..., 0], p[..., 1], p[..., 2], lat0, lon0, h0)
    return np.stack([np.asarray(lat), np.asarray(lon), np.asarray(h)], axis=-1)


def geodetic_to_enu(lla: ArrayLike, origin: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`enu_to_geodetic`."""
    q = _triples(lla, "lla")
    lat0, lon0, h0 = _origin(origin)
    e, n, u = pymap3d.geodetic2enu(q[..., 0], q[..., 1], q[..., 2], lat0, lon0, h0)
    return np.stack([np.asarray(e), np.asarray(n), np.asarray(u)], axis=-1)


def _compass_deg(yaw_enu: float) -> float:
    """ENU yaw (rad, from east, counter-clockwise) to a compass heading in [0, 360) degrees."""
    return (90.0 - math.degrees(yaw_enu)) % 360.0


def mission_items(trajectory: Trajectory, origin: ArrayLike) -> list[MissionItem]:
    """The mission items of one UAV's trajectory (docs/hardware-mavlink.md), item 0 = home."""
    lat0, lon0, h0 = _origin(origin)
    wps = trajectory.waypoints
    pos = np.array([w.pos for w in wps], float)
    lla = enu_to_geodetic(pos, (lat0, lon0, h0))
    items: list[MissionItem] = [
        MissionItem(0, 1, MAV_FRAME_GLOBAL, MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0, lat0, lon0, h0)),
        MissionItem(1, 0, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_NAV_TAKEOFF,
                    (0, 0, 0, 0, float(lla[0, 0]), float(lla[0, 1]), float(pos[0, 2]))),
    ]

    def add(frame: int, command: int, params: tuple[float, ...]) -> None:
        items.append(MissionItem(len(items), 0, frame, command, tuple(float(v) for v in params)))  # type: ignore[arg-type]

    speed: float | None = None
    heading: float | None = None
    for k, (w, (lat, lon, _h), p) in enumerate(zip(wps, lla, pos)):
        hdg = _compass_deg(w.yaw)
        nxt = k + 1 < len(wps)
        dt = wps[k + 1].t - w.t if nxt else 0.0
        length = float(np.linalg.norm(pos[k + 1] - p)) if nxt else 0.0
        hold = dt if nxt and length < 0.01 else 0.0
        add(MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_NAV_WAYPOINT, (hold, 0, 0, hdg, float(lat), float(lon), float(p[2])))
        if heading is None or abs((hdg - heading + 180.0) % 360.0 - 180.0) > 0.5:
            add(MAV_FRAME_MISSION, MAV_CMD_CONDITION_YAW, (hdg, 0, 0, 0, 0, 0, 0))
            heading = hdg
        if w.capture_id is not None:
            add(MAV_FRAME_MISSION, MAV_CMD_DO_DIGICAM_CONTROL, AI.capture_params(w.capture_id))
        if nxt and length >= 0.01:
            v = length / dt
            if speed is None or abs(v - speed) > 0.01:
                add(MAV_FRAME_MISSION, MAV_CMD_DO_CHANGE_SPEED, AI.speed_params(min(v, 100.0)))
                speed = v
    add(MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_NAV_RETURN_TO_LAUNCH, (0, 0, 0, 0, 0, 0, 0))
    return items
