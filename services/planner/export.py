"""Mission export: QGroundControl .plan, QGC WPL 110 waypoint files, KML and GeoJSON, and their readers.

Design notes: docs/planner.md (services/planner/export.py).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge.geometry import ardupilot_items as AI
from edge.geometry.waypoint_mission import (  # noqa: F401  (their home; exported here too)
    MAV_CMD_CONDITION_YAW,
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_DO_DIGICAM_CONTROL,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_MISSION,
    MissionItem,
    _compass_deg,
    _origin,
    enu_to_geodetic,
    geodetic_to_enu,
    mission_items,
)
from protocol import codec
from protocol.messages import MissionPlan, Trajectory
from protocol.textsafe import xml_text

__all__ = ["MAV_CMD_NAV_WAYPOINT", "MAV_CMD_NAV_TAKEOFF", "MAV_CMD_NAV_RETURN_TO_LAUNCH", "MAV_CMD_DO_DIGICAM_CONTROL",
           "MissionItem", "enu_to_geodetic", "geodetic_to_enu", "mission_items", "leg_speeds", "qgc_wpl",
           "parse_qgc_wpl", "qgc_plan", "parse_qgc_plan", "mission_kml", "parse_kml", "waypoints_enu",
           "mission_geojson", "parse_geojson", "write_mission"]

MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION = AI.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
MAV_CMD_NAV_RALLY_POINT = AI.MAV_CMD_NAV_RALLY_POINT
#: the return altitude of the rally point in a .plan (ArduCopter's RTL_ALT default), m above home
RALLY_ALT_M = 15.0
HEADER = "QGC WPL 110"


def _fmt(x: float, digits: int) -> str:
    s = f"{x:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def qgc_wpl(trajectory: Trajectory, origin: ArrayLike) -> str:
    """The QGC WPL 110 text of one UAV's trajectory (docs/planner.md)."""
    lines = [HEADER]
    for it in mission_items(trajectory, origin):
        p = it.params
        cells = [str(it.index), str(it.current), str(it.frame), str(it.command),
                 *(_fmt(v, 6) for v in p[:4]), _fmt(p[4], 9), _fmt(p[5], 9), _fmt(p[6], 3),
                 str(it.autocontinue)]
        lines.append("\t".join(cells))
    return "\n".join(lines) + "\n"


def parse_qgc_wpl(text: str) -> list[MissionItem]:
    """Parse a QGC WPL 110 file (tabs or spaces) into its items; ValueError naming the line on a missing
    header, a line without 12 fields or a non-numeric field."""
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
    pts: list[tuple[float, float, float]] = []
    caps: list[int | None] = []
    for it in items[1:]:
        if it.command == MAV_CMD_NAV_WAYPOINT:
            lat, lon, alt = it.params[4:7]
            h = alt + origin[2] if it.frame == MAV_FRAME_GLOBAL_RELATIVE_ALT else alt
            pts.append((lat, lon, h))
            caps.append(None)
        elif it.command == MAV_CMD_DO_DIGICAM_CONTROL and caps:
            caps[-1] = AI.capture_id(it.params)
    enu = geodetic_to_enu(np.asarray(pts, float).reshape(-1, 3), origin) if pts else np.zeros((0, 3))
    return enu, caps


def leg_speeds(items: list[MissionItem]) -> list[float | None]:
    """The DO_CHANGE_SPEED ground speed in force on the leg after each NAV_WAYPOINT (None: the default)."""
    out: list[float | None] = []
    speed: float | None = None
    for it in items[1:]:
        if it.command == MAV_CMD_DO_CHANGE_SPEED and it.params[1] > 0:
            speed = it.params[1]
            if out:
                out[-1] = speed  # after a waypoint: the leg that starts there
        elif it.command == MAV_CMD_NAV_WAYPOINT:
            out.append(speed)
    return out


def qgc_plan(trajectory: Trajectory, plan: MissionPlan) -> dict[str, Any]:
    """QGroundControl's .plan JSON for one UAV: the mission, the box as an inclusion fence, a rally point
    (QGroundControl's "Plan File Format"; the versions and fields: docs/planner.md)."""
    items = mission_items(trajectory, plan.origin)
    home = items[0].params
    out_items = [{"type": "SimpleItem", "autoContinue": bool(it.autocontinue), "command": it.command,
                  "doJumpId": it.index, "frame": it.frame,
                  "params": [v if math.isfinite(v) else None for v in it.params], "Altitude": it.params[6],
                  "AltitudeMode": 1, "AMSLAltAboveTerrain": None} for it in items[1:]]
    lo, hi = plan.geofence.lo, plan.geofence.hi
    ring = enu_to_geodetic([(lo[0], lo[1], 0.0), (hi[0], lo[1], 0.0), (hi[0], hi[1], 0.0), (lo[0], hi[1], 0.0)],
                           plan.origin)
    start = trajectory.waypoints[0].pos
    r = enu_to_geodetic([start[0], start[1], 0.0], plan.origin)
    speeds = [w.speed for w in trajectory.waypoints if w.speed > 0]
    return {
        "fileType": "Plan", "version": 1, "groundStation": "SkyNet Inspect",
        "mission": {"version": 2, "firmwareType": 3, "vehicleType": 2,
                    "cruiseSpeed": max(speeds) if speeds else 5.0, "hoverSpeed": max(speeds) if speeds else 5.0,
                    "plannedHomePosition": [home[4], home[5], home[6]], "items": out_items},
        "geoFence": {"version": 2, "circles": [],
                     "polygons": [{"inclusion": True, "version": 1,
                                   "polygon": [[float(a), float(b)] for a, b, _ in ring]}]},
        "rallyPoints": {"version": 2, "points": [[float(r[0]), float(r[1]), RALLY_ALT_M]]},
    }


def parse_qgc_plan(doc: dict[str, Any] | str) -> tuple[list[MissionItem], list[list[tuple[float, float]]],
                                                       list[tuple[float, float, float]]]:
    """Read a .plan: ``(items with home as item 0, inclusion polygons [(lat, lon)], rally points)``.

    Raises ValueError for anything that is not a version-2 Plan of SimpleItems.
    """
    d = codec.loads_json(doc) if isinstance(doc, str) else doc
    if not isinstance(d, dict) or d.get("fileType") != "Plan":
        raise ValueError("not a QGroundControl plan: fileType must be 'Plan'")
    m = d.get("mission") or {}
    if m.get("version") != 2:
        raise ValueError("only mission version 2 is read")
    home = m.get("plannedHomePosition")
    if not (isinstance(home, list) and len(home) == 3):
        raise ValueError("mission.plannedHomePosition must be [lat, lon, alt]")
    items = [MissionItem(0, 1, MAV_FRAME_GLOBAL, MAV_CMD_NAV_WAYPOINT, (0, 0, 0, 0, *map(float, home)))]  # type: ignore[arg-type]
    for k, it in enumerate(m.get("items", []), start=1):
        if it.get("type") != "SimpleItem":
            raise ValueError(f"mission item {k}: only SimpleItem is read, got {it.get('type')!r}")
        p = it.get("params")
        if not (isinstance(p, list) and len(p) == 7):
            raise ValueError(f"mission item {k}: params must have 7 entries")
        params = tuple(math.nan if v is None else float(v) for v in p)
        items.append(MissionItem(k, 0, int(it["frame"]), int(it["command"]), params,  # type: ignore[arg-type]
                                 int(bool(it.get("autoContinue", True)))))
    fence = [[(float(a), float(b)) for a, b in poly["polygon"]]
             for poly in (d.get("geoFence") or {}).get("polygons", []) if poly.get("inclusion", True)]
    rally = [tuple(map(float, r)) for r in (d.get("rallyPoints") or {}).get("points", [])]
    return items, fence, rally  # type: ignore[return-value]


def mission_kml(plan: MissionPlan, surface: ArrayLike | None = None) -> str:
    """KML 2.2 of a plan: a LineString per UAV, a Point per capture, the surface (4 ENU corners) as a Polygon."""
    o = plan.origin

    def coords(p: ArrayLike) -> str:
        g = enu_to_geodetic(np.asarray(p, float).reshape(-1, 3), o)
        return " ".join(f"{lon:.9f},{lat:.9f},{h:.3f}" for lat, lon, h in g)

    marks = [f"<Placemark><name>uav{tr.uav}</name><LineString><altitudeMode>absolute</altitudeMode>"
             f"<coordinates>{coords([w.pos for w in tr.waypoints])}</coordinates></LineString></Placemark>"
             for tr in plan.trajectories]
    marks += [f"<Placemark><name>capture {c.capture_id} (uav{c.uav})</name><Point><altitudeMode>absolute"
              f"</altitudeMode><coordinates>{coords(c.pos)}</coordinates></Point></Placemark>" for c in plan.captures]
    if surface is not None:
        corners = np.asarray(surface, float).reshape(-1, 3)
        ring = np.vstack([corners, corners[:1]])
        marks.append("<Placemark><name>inspected surface</name><Polygon><altitudeMode>absolute</altitudeMode>"
                     f"<outerBoundaryIs><LinearRing><coordinates>{coords(ring)}</coordinates></LinearRing>"
                     "</outerBoundaryIs></Polygon></Placemark>")
    name = xml_text(f"SkyNet Inspect mission ({plan.algorithm})")
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            f"<name>{name}</name>" + "".join(marks) + "</Document></kml>\n")


def parse_kml(text: str, origin: ArrayLike) -> dict[str, NDArray[np.float64]]:
    """Placemark name -> its coordinates in ENU ``(N, 3)`` (every LineString, Point and Polygon ring)."""
    import xml.etree.ElementTree as ET

    ns = {"k": "http://www.opengis.net/kml/2.2"}
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f"not KML: {exc}") from None
    out: dict[str, NDArray[np.float64]] = {}
    for pm in root.iterfind(".//k:Placemark", ns):
        name = pm.findtext("k:name", default="", namespaces=ns)
        c = pm.find(".//k:coordinates", ns)
        if c is None or not c.text:
            continue
        lla = np.array([[float(v) for v in t.split(",")] for t in c.text.split()], float)
        out[name] = geodetic_to_enu(lla[:, [1, 0, 2]], origin)
    return out


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
    d = codec.loads_json(doc) if isinstance(doc, str) else doc
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


def write_mission(plan: MissionPlan, out_dir: str | Path, surface: ArrayLike | None = None) -> list[Path]:
    """Write ``uav<N>.waypoints`` and ``uav<N>.plan`` per UAV, ``mission.geojson`` and ``mission.kml``."""
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []

    def put(name: str, text: str) -> None:
        (d / name).write_text(text)
        paths.append(d / name)

    for tr in plan.trajectories:
        put(f"uav{tr.uav}.waypoints", qgc_wpl(tr, plan.origin))
        put(f"uav{tr.uav}.plan", json.dumps(qgc_plan(tr, plan), indent=1))
    put("mission.geojson", json.dumps(mission_geojson(plan), indent=1))
    put("mission.kml", mission_kml(plan, surface))
    return paths
