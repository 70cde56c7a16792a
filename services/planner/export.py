"""Mission export: QGroundControl / Mission Planner waypoint files and GeoJSON, and their parsers.

The paper uploads the paths to the UAVs with Mission Planner (PAPER.md Section 4). Each UAV's
trajectory becomes a plain-text "QGC WPL 110" mission, one item per line, tab-separated::

    INDEX  CURRENT  FRAME  COMMAND  P1  P2  P3  P4  LAT/X  LON/Y  ALT/Z  AUTOCONTINUE

- item 0: home, ``MAV_CMD_NAV_WAYPOINT`` (16) in ``MAV_FRAME_GLOBAL`` (0), absolute altitude;
- item 1: ``MAV_CMD_NAV_TAKEOFF`` (22) to the first waypoint's altitude;
- waypoints: ``MAV_CMD_NAV_WAYPOINT`` (16) in ``MAV_FRAME_GLOBAL_RELATIVE_ALT`` (3), altitude
  above home, P4 = yaw as a compass heading in degrees (0 north, clockwise);
- after each capture waypoint: ``MAV_CMD_DO_DIGICAM_CONTROL`` (203) with P5 = 1 (shoot) and
  P7 = the capture id (the "command identity" parameter);
- last item: ``MAV_CMD_NAV_RETURN_TO_LAUNCH`` (20).

Local ENU metres are converted to WGS-84 with :func:`pymap3d.enu2geodetic` about the scenario's
geodetic origin; latitudes/longitudes are written with 9 decimals (0.1 mm), altitudes with 3.
The paths also go out as a GeoJSON FeatureCollection (RFC 7946: ``[lon, lat, alt]``): one
LineString per UAV and for the centroid, a Point per capture, and the geofence as a Polygon.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray

from protocol.messages import MissionPlan, Trajectory

__all__ = [
    "MAV_CMD_NAV_WAYPOINT",
    "MAV_CMD_NAV_TAKEOFF",
    "MAV_CMD_NAV_RETURN_TO_LAUNCH",
    "MAV_CMD_DO_DIGICAM_CONTROL",
    "MissionItem",
    "enu_to_geodetic",
    "geodetic_to_enu",
    "qgc_wpl",
    "parse_qgc_wpl",
    "waypoints_enu",
    "mission_geojson",
    "parse_geojson",
    "write_mission",
]

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_DO_DIGICAM_CONTROL = 203
MAV_FRAME_GLOBAL = 0
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
HEADER = "QGC WPL 110"


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


def enu_to_geodetic(enu: ArrayLike, origin: ArrayLike) -> NDArray[np.float64]:
    """Local ENU metres ``(..., 3)`` to ``(..., 3)`` latitude, longitude (deg), altitude (m)."""
    p = np.asarray(enu, float)
    if p.shape[-1:] != (3,) or not np.all(np.isfinite(p)):
        raise ValueError("enu must be finite with a last axis of 3")
    lat0, lon0, h0 = _origin(origin)
    lat, lon, h = pymap3d.enu2geodetic(p[..., 0], p[..., 1], p[..., 2], lat0, lon0, h0)
    return np.stack([np.asarray(lat), np.asarray(lon), np.asarray(h)], axis=-1)


def geodetic_to_enu(lla: ArrayLike, origin: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`enu_to_geodetic`."""
    q = np.asarray(lla, float)
    if q.shape[-1:] != (3,) or not np.all(np.isfinite(q)):
        raise ValueError("lla must be finite with a last axis of 3")
    lat0, lon0, h0 = _origin(origin)
    e, n, u = pymap3d.geodetic2enu(q[..., 0], q[..., 1], q[..., 2], lat0, lon0, h0)
    return np.stack([np.asarray(e), np.asarray(n), np.asarray(u)], axis=-1)


def _compass_deg(yaw_enu: float) -> float:
    """ENU yaw (rad, from east, counter-clockwise) to a compass heading in [0, 360) degrees."""
    return (90.0 - math.degrees(yaw_enu)) % 360.0


def _fmt(x: float, digits: int) -> str:
    s = f"{x:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def qgc_wpl(trajectory: Trajectory, origin: ArrayLike) -> str:
    """The QGC WPL 110 text of one UAV's trajectory (see the module docstring)."""
    lat0, lon0, h0 = _origin(origin)
    wps = trajectory.waypoints
    pos = np.array([w.pos for w in wps], float)
    lla = enu_to_geodetic(pos, (lat0, lon0, h0))
    items: list[MissionItem] = [
        MissionItem(0, 1, MAV_FRAME_GLOBAL, MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0, lat0, lon0, h0)),
        MissionItem(1, 0, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_NAV_TAKEOFF,
                    (0, 0, 0, 0, float(lla[0, 0]), float(lla[0, 1]), float(pos[0, 2]))),
    ]
    for w, (lat, lon, _h), p in zip(wps, lla, pos):
        items.append(MissionItem(len(items), 0, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_NAV_WAYPOINT,
                                 (0, 0, 0, _compass_deg(w.yaw), float(lat), float(lon), float(p[2]))))
        if w.capture_id is not None:
            items.append(MissionItem(len(items), 0, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_DO_DIGICAM_CONTROL,
                                     (0, 0, 0, 0, 1, 0, float(w.capture_id))))
    items.append(MissionItem(len(items), 0, MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_CMD_NAV_RETURN_TO_LAUNCH,
                             (0, 0, 0, 0, 0, 0, 0)))
    lines = [HEADER]
    for it in items:
        p = it.params
        cells = [str(it.index), str(it.current), str(it.frame), str(it.command),
                 *(_fmt(v, 6) for v in p[:4]), _fmt(p[4], 9), _fmt(p[5], 9), _fmt(p[6], 3),
                 str(it.autocontinue)]
        lines.append("\t".join(cells))
    return "\n".join(lines) + "\n"


def parse_qgc_wpl(text: str) -> list[MissionItem]:
    """Parse a QGC WPL 110 file (tabs or spaces) into its items.

    Raises
    ------
    ValueError
        On a missing header, a line without 12 fields or a non-numeric field (naming the line).
    """
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines or lines[0].split() != HEADER.split():
        raise ValueError(f"not a waypoint file: the first line must be {HEADER!r}")
    items = []
    for no, ln in enumerate(lines[1:], start=2):
        f = ln.split()
        if len(f) != 12:
            raise ValueError(f"line {no}: expected 12 fields, got {len(f)}")
        try:
            params = tuple(float(x) for x in f[4:11])
            ints = [int(f[0]), int(f[1]), int(f[2]), int(f[3]), int(f[11])]
        except ValueError:
            raise ValueError(f"line {no}: non-numeric field") from None
        if not all(math.isfinite(v) for v in params):
            raise ValueError(f"line {no}: non-finite parameter")
        items.append(MissionItem(ints[0], ints[1], ints[2], ints[3], params, ints[4]))  # type: ignore[arg-type]
    return items


def waypoints_enu(items: list[MissionItem]) -> tuple[NDArray[np.float64], list[int | None]]:
    """ENU positions ``(K, 3)`` of the NAV_WAYPOINT items after home, and each one's capture id.

    Home (item 0) is the geodetic origin; relative altitudes are above it.
    """
    if not items or items[0].command != MAV_CMD_NAV_WAYPOINT:
        raise ValueError("the first item must be the home waypoint")
    origin = items[0].params[4:7]
    pts, caps = [], []
    for it in items[1:]:
        if it.command == MAV_CMD_NAV_WAYPOINT:
            lat, lon, alt = it.params[4:7]
            h = alt + origin[2] if it.frame == MAV_FRAME_GLOBAL_RELATIVE_ALT else alt
            pts.append((lat, lon, h))
            caps.append(None)
        elif it.command == MAV_CMD_DO_DIGICAM_CONTROL and caps:
            caps[-1] = int(it.params[6])
    enu = geodetic_to_enu(np.asarray(pts, float).reshape(-1, 3), origin) if pts else np.zeros((0, 3))
    return enu, caps


def mission_geojson(plan: MissionPlan) -> dict[str, Any]:
    """GeoJSON FeatureCollection of a plan: centroid and UAV paths, captures, geofence."""
    o = plan.origin

    def coords(p: ArrayLike) -> list[list[float]]:
        g = enu_to_geodetic(np.asarray(p, float).reshape(-1, 3), o)
        return [[round(float(lon), 9), round(float(lat), 9), round(float(h), 3)] for lat, lon, h in g]

    feats: list[dict[str, Any]] = [
        {"type": "Feature", "properties": {"kind": "centroid"},
         "geometry": {"type": "LineString", "coordinates": coords(plan.centroid_path)}}
    ]
    for tr in plan.trajectories:
        feats.append({"type": "Feature", "properties": {"kind": "uav", "uav": tr.uav},
                      "geometry": {"type": "LineString", "coordinates": coords([w.pos for w in tr.waypoints])}})
    for c in plan.captures:
        feats.append({"type": "Feature",
                      "properties": {"kind": "capture", "uav": c.uav, "capture_id": c.capture_id, "t": c.t,
                                     "look": list(c.look)},
                      "geometry": {"type": "Point", "coordinates": coords(c.pos)[0]}})
    lo, hi = plan.geofence.lo, plan.geofence.hi
    ring = [(lo[0], lo[1], 0.0), (hi[0], lo[1], 0.0), (hi[0], hi[1], 0.0), (lo[0], hi[1], 0.0), (lo[0], lo[1], 0.0)]
    feats.append({"type": "Feature", "properties": {"kind": "geofence", "floor_m": lo[2], "ceiling_m": hi[2]},
                  "geometry": {"type": "Polygon", "coordinates": [[c[:2] for c in coords(ring)]]}})
    return {"type": "FeatureCollection", "properties": {"origin": list(o), "algorithm": plan.algorithm},
            "features": feats}


def parse_geojson(doc: dict[str, Any] | str, origin: ArrayLike) -> dict[str, NDArray[np.float64]]:
    """Read the LineStrings back to ENU: ``{"centroid": (N, 3), "uav1": ..., ...}``."""
    d = json.loads(doc) if isinstance(doc, str) else doc
    if not isinstance(d, dict) or d.get("type") != "FeatureCollection":
        raise ValueError("not a GeoJSON FeatureCollection")
    out: dict[str, NDArray[np.float64]] = {}
    for f in d.get("features", []):
        g, props = f.get("geometry") or {}, f.get("properties") or {}
        if g.get("type") != "LineString":
            continue
        c = np.asarray(g["coordinates"], float)
        if c.ndim != 2 or c.shape[1] != 3:
            raise ValueError("LineString coordinates must be [lon, lat, alt] triples")
        name = "centroid" if props.get("kind") == "centroid" else f"uav{props.get('uav')}"
        out[name] = geodetic_to_enu(c[:, [1, 0, 2]], origin)
    return out


def write_mission(plan: MissionPlan, out_dir: str | Path) -> list[Path]:
    """Write ``uav<N>.waypoints`` per UAV and ``mission.geojson`` into ``out_dir``; returns the paths."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for tr in plan.trajectories:
        p = d / f"uav{tr.uav}.waypoints"
        p.write_text(qgc_wpl(tr, plan.origin))
        paths.append(p)
    p = d / "mission.geojson"
    p.write_text(json.dumps(mission_geojson(plan), indent=1))
    paths.append(p)
    return paths
