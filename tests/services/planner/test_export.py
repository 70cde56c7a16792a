"""Mission interchange read back by the readers users have: pymavlink's mavwp for QGC WPL 110,
MAVSDK's QGroundControl .plan importer (and the .plan schema as QGC documents it), KML by XML."""

from __future__ import annotations

import json

import numpy as np
import pytest

from edge.geometry import ardupilot_items as AI
from services.planner.export import (
    MAV_CMD_CONDITION_YAW,
    MAV_CMD_DO_CHANGE_SPEED,
    MAV_CMD_DO_DIGICAM_CONTROL,
    MAV_CMD_NAV_WAYPOINT,
    leg_speeds,
    mission_items,
    mission_kml,
    parse_kml,
    parse_qgc_plan,
    parse_qgc_wpl,
    qgc_plan,
    qgc_wpl,
    waypoints_enu,
    write_mission,
)
from services.planner.mission import plan_details
from services.planner.scenario import load_scenario

SC = load_scenario()


@pytest.fixture(scope="module")
def plan():
    p, _, _ = plan_details(SC, seed=0, particles=40, iterations=40)
    return p


def planned_leg_speeds(tr) -> list[float | None]:
    P = np.array([w.pos for w in tr.waypoints])
    T = np.array([w.t for w in tr.waypoints])
    L = np.linalg.norm(np.diff(P, axis=0), axis=1)
    return [float(l / dt) if l >= 0.01 else None for l, dt in zip(L, np.diff(T))]


def test_wpl_read_by_pymavlink_has_speed_items_and_capture_ids_in_param6(plan, tmp_path):
    mavwp = pytest.importorskip("pymavlink.mavwp", reason="needs the 'mavlink' extra")
    for tr in plan.trajectories:
        path = tmp_path / f"uav{tr.uav}.waypoints"
        path.write_text(qgc_wpl(tr, plan.origin))
        wp = mavwp.MAVWPLoader()
        n = wp.load(str(path))
        mine = mission_items(tr, plan.origin)
        assert n == wp.count() == len(mine)
        read = [wp.wp(i) for i in range(wp.count())]
        assert [r.command for r in read] == [m.command for m in mine]
        # capture ids: param6 of DO_DIGICAM_CONTROL (shoot = param5 1), param7 (test shot) 0;
        # MISSION_ITEM carries param5..7 in x, y, z
        shots = [r for r in read if r.command == MAV_CMD_DO_DIGICAM_CONTROL]
        assert [int(r.y) for r in shots] == [w.capture_id for w in tr.waypoints if w.capture_id is not None]
        assert all(r.x == 1 and r.z == 0 for r in shots)
        # speed items: the planned ground speed of every leg within 1 cm/s
        assert any(r.command == MAV_CMD_DO_CHANGE_SPEED for r in read)
        got = leg_speeds(parse_qgc_wpl(path.read_text()))
        want = planned_leg_speeds(tr)
        for g, w in zip(got[:-1], want):
            if w is not None:
                assert g == pytest.approx(w, abs=0.011)
        # positions as pymavlink reads them
        nav = [r for r in read[2:] if r.command == MAV_CMD_NAV_WAYPOINT]
        enu, caps = waypoints_enu(parse_qgc_wpl(path.read_text()))
        assert len(nav) == len(tr.waypoints) and np.max(np.abs(enu - [w.pos for w in tr.waypoints])) < 0.01
        assert caps == [w.capture_id for w in tr.waypoints]
        yaw = [r for r in read if r.command == MAV_CMD_CONDITION_YAW]
        assert yaw and all(0 <= r.param1 < 360 and r.param4 == 0 for r in yaw)


def test_capture_convention_rejects_what_a_float32_cannot_carry():
    assert AI.capture_params(7)[5] == 7.0 and AI.capture_id(AI.capture_params(7)) == 7
    assert AI.capture_id((0, 0, 0, 0, 0, 7, 0)) is None  # param5 0: no shot
    for bad in (-1, AI.MAX_CAPTURE_ID + 1, 1.5):
        with pytest.raises(ValueError):
            AI.capture_params(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        AI.speed_params(0.0)


def test_plan_follows_qgc_schema_and_reads_back(plan):
    tr = plan.trajectories[0]
    doc = json.loads(json.dumps(qgc_plan(tr, plan)))  # through JSON text, as a file would
    assert doc["fileType"] == "Plan" and doc["version"] == 1
    m = doc["mission"]
    assert m["version"] == 2 and m["firmwareType"] == 3 and m["vehicleType"] == 2
    assert len(m["plannedHomePosition"]) == 3
    assert all(it["type"] == "SimpleItem" and len(it["params"]) == 7 and isinstance(it["autoContinue"], bool)
               for it in m["items"])
    assert doc["geoFence"]["version"] == 2 and len(doc["geoFence"]["polygons"][0]["polygon"]) == 4
    assert doc["rallyPoints"]["version"] == 2 and len(doc["rallyPoints"]["points"][0]) == 3
    items, fence, rally = parse_qgc_plan(doc)
    mine = mission_items(tr, plan.origin)
    assert [(i.command, i.frame) for i in items] == [(i.command, i.frame) for i in mine]
    assert np.allclose([i.params for i in items[1:]], [i.params for i in mine[1:]], atol=1e-9)
    assert len(fence) == 1 and len(rally) == 1
    with pytest.raises(ValueError, match="fileType"):
        parse_qgc_plan({"fileType": "Mission"})
    with pytest.raises(ValueError, match="SimpleItem"):
        parse_qgc_plan({**doc, "mission": {**m, "items": [{"type": "ComplexItem"}]}})


def test_plan_imported_by_mavsdk_and_uploaded_to_the_sim_autopilot(plan):
    """MAVSDK's own QGroundControl importer reads the .plan; the mission, fence and rally go to an autopilot."""
    pytest.importorskip("mavsdk", reason="needs the 'mavsdk' wheel (test extra)")
    pytest.importorskip("pymavlink", reason="the sim autopilot needs the 'mavlink' extra")
    import asyncio
    import socket

    from mavsdk import ComponentType
    from mavsdk.asyncio import Configuration, Mavsdk
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync

    from edge.vehicle.mavsim import MavlinkSimVehicle

    tr = plan.trajectories[1]
    text = json.dumps(qgc_plan(tr, plan))
    mine = mission_items(tr, plan.origin)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 2, origin=plan.origin).start()

    async def go():
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
            await sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            system = await sdk.first_autopilot(10.0)
            assert system is not None
            raw = MissionRawAsync(system)
            data = await raw.import_qgroundcontrol_mission_from_string(text)
            await raw.upload_geofence(data.geofence_items)
            await raw.upload_rally_points(data.rally_items)
            await raw.upload_mission(data.mission_items)
            return data, await raw.download_mission()

    try:
        data, back = asyncio.run(asyncio.wait_for(go(), 120))
    finally:
        veh.close()
    assert [i.command for i in data.mission_items] == [i.command for i in mine]  # home is item 0
    assert [i.command for i in back] == [i.command for i in mine]
    for got, want in zip(back[1:], mine[1:]):
        if want.command == MAV_CMD_NAV_WAYPOINT:
            assert (got.x, got.y) == (round(want.params[4] * 1e7), round(want.params[5] * 1e7))
            assert got.z == pytest.approx(want.params[6], abs=1e-3)
    assert [it.command for it in veh.missions.stores[1]] == [5001] * 4
    assert [it.command for it in veh.missions.stores[2]] == [5100]


def test_kml_paths_captures_and_surface(plan, tmp_path):
    text = mission_kml(plan, SC.surface.corners)
    back = parse_kml(text, plan.origin)
    for tr in plan.trajectories:
        assert np.max(np.abs(back[f"uav{tr.uav}"] - [w.pos for w in tr.waypoints])) < 0.01
    assert sum(k.startswith("capture ") for k in back) == len(plan.captures) == 26
    assert np.max(np.abs(back["inspected surface"][:4] - np.asarray(SC.surface.corners))) < 0.01
    with pytest.raises(ValueError, match="KML"):
        parse_kml("<kml", plan.origin)
    files = write_mission(plan, tmp_path, SC.surface.corners)
    assert {f.name for f in files} >= {"uav1.waypoints", "uav1.plan", "mission.geojson", "mission.kml"}


def test_a_hostile_algorithm_name_is_data_in_the_kml_and_the_geojson(plan, tmp_path):
    """The plan comes from another node: its text reaches the KML and GeoJSON files as data, read back intact
    by an XML parser (KML) and a GeoJSON reader."""
    import geojson
    from lxml import etree

    from protocol.textsafe import printable
    from tests.protocol.test_textsafe import HOSTILE

    rogue = plan.model_copy(update={"algorithm": HOSTILE})
    files = {f.name: f for f in write_mission(rogue, tmp_path, SC.surface.corners)}
    root = etree.fromstring(files["mission.kml"].read_bytes())
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    assert root.findtext("k:Document/k:name", namespaces=ns) == printable(f"SkyNet Inspect mission ({HOSTILE})")
    assert len(root.findall(".//k:Placemark", ns)) == len(plan.trajectories) + len(plan.captures) + 1
    doc = geojson.loads(files["mission.geojson"].read_text())
    assert doc.is_valid, doc.errors()
    assert doc["properties"]["algorithm"] == HOSTILE  # JSON carries every character as it came
    assert np.max(np.abs(parse_kml(files["mission.kml"].read_text(), plan.origin)["uav1"]
                         - [w.pos for w in plan.trajectories[0].waypoints])) < 0.01
