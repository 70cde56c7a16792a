"""The sim autopilot's pure cores: parameters, stream scheduler, mission protocol, AUTO, mode rules."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from edge.geometry import ardupilot_items as I
from edge.vehicle.apm.auto import AutoMission
from edge.vehicle.apm.missions import FENCE, MISSION, RALLY, MissionServer, PlanItem, item_from_message
from edge.vehicle.apm.modes import CopterMode, check_mode_change
from edge.vehicle.apm.params import ParamTable
from edge.vehicle.apm.streams import StreamScheduler

GCS = (255, 190)


# ---------------------------------------------------------------------------------- params
def test_param_table_protocol_and_bad_values():
    t = ParamTable(SYSID_THISMAV=3)
    names = [s.name for s in t.specs]
    assert names == sorted(names) and t["SYSID_THISMAV"] == 3
    listed = t.request_list()
    assert len(listed) == len(names) and listed[0][1]["param_count"] == len(names)
    assert [o[1]["param_index"] for o in listed] == list(range(len(names)))
    (one,) = t.request_read(b"RTL_ALT\0\0\0", -1)
    assert one[1]["param_value"] == 1500 and one[1]["param_id"] == b"RTL_ALT"
    assert t.request_read("NOPE", -1) == [] and t.request_read("", 999) == []
    assert t.param_set("WPNAV_SPEED", 500.0)[0][1]["param_value"] == 500.0
    for bad in (math.nan, math.inf, 1e9, -5.0):
        assert t.param_set("WPNAV_SPEED", bad)[0][1]["param_value"] == 500.0  # unchanged value answered
    assert t.param_set("FS_GCS_ENABLE", 1.5)[0][1]["param_value"] == 0  # an int parameter takes integers only
    assert t.param_set("NO_SUCH_PARAM", 1.0) == []
    assert t.rejected == 6
    with pytest.raises(ValueError):
        ParamTable(FS_GCS_TIMEOUT=0.5)


# ---------------------------------------------------------------------------------- streams
def test_stream_scheduler_intervals_and_legacy_groups():
    s = StreamScheduler({"ATTITUDE": 30, "SYS_STATUS": 1, "VFR_HUD": 74}, {"ATTITUDE": 10.0, "SYS_STATUS": 2.0})
    assert set(s.due(0.0)) == {"ATTITUDE", "SYS_STATUS"}  # VFR_HUD off by default here
    assert s.due(0.05) == [] and s.due(0.1) == ["ATTITUDE"]
    assert s.set_interval(30, 200_000) and s.rate["ATTITUDE"] == 5.0 and s.interval_us(30) == 200_000
    assert s.set_interval(30, 1) and s.rate["ATTITUDE"] == 50.0  # capped
    assert s.set_interval(30, -1) and s.interval_us(30) == -1
    assert s.set_interval(30, 0) and s.rate["ATTITUDE"] == 10.0  # back to the default
    assert not s.set_interval(9999, 1000) and not s.set_interval(math.nan, 1000) and not s.set_interval(30.5, 1)
    assert s.interval_us(9999) is None
    assert s.request_data_stream(11, 4, 1) and s.rate["VFR_HUD"] == 4.0  # EXTRA2
    assert s.request_data_stream(0, 0, 0) and s.rate == {"ATTITUDE": 0.0, "SYS_STATUS": 0.0, "VFR_HUD": 0.0}
    assert not s.request_data_stream(99, 4, 1)


# ---------------------------------------------------------------------------------- missions
def wp(seq, cmd=16, frame=3, x=-338760100, y=1511911820, z=10.0, mission_type=MISSION, **p):
    return PlanItem(seq, frame, cmd, x=x, y=y, z=z, mission_type=mission_type, **p)


def test_upload_download_clear_and_a_second_sender():
    ms = MissionServer(home=lambda: wp(0, frame=0, z=0.0))
    out = ms.count(GCS, MISSION, 3, 0.0)
    assert out == [("mission_request_int", dict(target_system=255, target_component=190, seq=0, mission_type=0))]
    assert ms.count((200, 1), MISSION, 2, 0.0)[0][1]["type"] == 14  # DENIED while GCS uploads
    ms.item(GCS, wp(0, frame=0), True, 0.1)
    assert ms.item(GCS, wp(0, frame=0), True, 0.2)[0][1]["seq"] == 1  # a duplicate: ask for 1 again
    assert ms.item(GCS, wp(2), True, 0.2)[0][1]["seq"] == 1  # out of order: ask for 1 again
    ms.item(GCS, wp(1, cmd=22), True, 0.3)
    (ack,) = ms.item(GCS, wp(2), True, 0.4)
    assert ack[0] == "mission_ack" and ack[1]["type"] == 0 and len(ms.mission()) == 3
    assert ms.request_list(GCS, MISSION)[0][1]["count"] == 3
    item0 = ms.request(GCS, MISSION, 0, True)[0][1]
    assert item0["frame"] == 0 and item0["z"] == 0.0  # home, whatever was uploaded at 0
    assert ms.request(GCS, MISSION, 3, True)[0][1]["type"] == 13  # INVALID_SEQUENCE
    legacy = ms.request(GCS, MISSION, 2, False)[0]
    assert legacy[0] == "mission_item" and legacy[1]["x"] == pytest.approx(-33.87601)
    assert ms.clear(GCS, MISSION)[0][1]["type"] == 0 and ms.mission() == []
    assert ms.request_list(GCS, MISSION)[0][1]["count"] == 1  # home only


def test_bad_items_are_refused_and_a_silent_sender_times_out():
    ms = MissionServer()
    ms.count(GCS, MISSION, 2, 0.0)
    assert ms.item(GCS, wp(0, cmd=31337), True, 0.1)[0][1]["type"] == 3  # UNSUPPORTED command
    assert not ms.busy and ms.mission() == []
    ms.count(GCS, MISSION, 2, 0.0)
    assert ms.item(GCS, wp(0, z=math.nan), True, 0.1)[0][1]["type"] == 5  # INVALID
    ms.count(GCS, MISSION, 2, 0.0)
    assert ms.item(GCS, wp(0, frame=1), True, 0.1)[0][1]["type"] == 2  # UNSUPPORTED_FRAME (local NED)
    ms.count(GCS, FENCE, 1, 0.0)
    assert ms.item(GCS, wp(0, cmd=16, mission_type=FENCE), True, 0.1)[0][1]["type"] == 3  # a waypoint in a fence
    assert ms.count(GCS, 7, 1, 0.0)[0][1]["type"] == 3 and ms.count(GCS, MISSION, 10**6, 0.0)[0][1]["type"] == 1
    ms.count(GCS, RALLY, 1, 0.0)
    outs = [ms.tick(t) for t in (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)]
    assert outs[0] == [] and all(o[0][0] == "mission_request_int" for o in outs[1:-1])
    assert outs[-1][0][1]["type"] == 15 and not ms.busy  # OPERATION_CANCELLED after 5 re-requests
    assert ms.item(GCS, wp(0, cmd=5100, mission_type=RALLY), True, 7.0) == []  # no transfer: ignored
    assert ms.count(GCS, MISSION, 0, 8.0)[0][1]["type"] == 0  # count 0 clears
    assert ms.clear(GCS, 255)[0][1]["type"] == 0


def test_legacy_float_items_are_converted():
    msg = SimpleNamespace(seq=0, frame=3, command=16, current=0, autocontinue=1, param1=0, param2=0, param3=0,
                          param4=0, x=-33.87601, y=151.191182, z=5.0, mission_type=0)
    it = item_from_message(msg, False)
    assert (it.x, it.y) == (-338760100, 1511911820)
    assert item_from_message(SimpleNamespace(**{**msg.__dict__, "x": math.nan}), False).x == 0


# ---------------------------------------------------------------------------------- AUTO
def flat(it: PlanItem):
    return (float(it.x), float(it.y), it.z)  # a toy projection: x, y are metres here


def test_auto_walks_takeoff_speed_camera_waypoint_land():
    items = [wp(0), PlanItem(1, 3, 22, z=5.0),
             PlanItem(2, 2, 178, param1=1, param2=2.0),
             PlanItem(3, 3, 16, x=10, y=0, z=5.0),
             PlanItem(4, 2, 203, param1=0, param2=0, param3=0, param4=0, x=1, y=9, z=0),
             PlanItem(5, 3, 21)]
    # x, y of DO_DIGICAM_CONTROL are param5, param6: shoot, capture 9 (in the MISSION_MAVLINK frame 2)
    a = AutoMission(items, flat, (0.0, 0.0, 0.0), speed=5.0, radius=0.5)
    fl, ev = a.update(0.0, (0, 0, 0), 0.0, airborne=False)
    assert fl.kind == "takeoff" and fl.alt == 5.0 and ev == [("current", 1)]
    fl, ev = a.update(1.0, (0, 0, 4.8), 0.0, airborne=True)
    assert ("reached", 1) in ev and a.speed == 2.0 and fl.kind == "goto"
    assert fl.pos[0] < 0.1 and fl.vel == pytest.approx((2.0, 0.0, 0.0))  # the carrot leaves at 2 m/s
    fl, _ = a.update(3.0, (4, 0, 5), 0.0, True)
    assert fl.pos == pytest.approx((4.0, 0.0, 5.0))
    fl, ev = a.update(6.0, (9.8, 0, 5), 0.0, True)
    assert ("reached", 3) in ev and ("shot", 9) in ev and fl.kind == "land"
    fl, ev = a.update(9.0, (10, 0, 0), 0.0, airborne=False)
    assert ("reached", 5) in ev and a.done and fl.kind == "hold"


def test_a_speed_command_mid_leg_moves_the_carrot_on_without_a_jump():
    items = [wp(0), PlanItem(1, 3, 16, x=0, y=0, z=5.0), PlanItem(2, 3, 16, x=20, y=0, z=5.0)]
    a = AutoMission(items, flat, (0.0, 0.0, 0.0), speed=2.0, radius=0.5, start=2)
    a._last_target = (0.0, 0.0, 5.0)
    fl, _ = a.update(0.0, (0, 0, 5), 0.0, True)
    fl, _ = a.update(3.0, (6, 0, 5), 0.0, True)
    assert fl.pos[0] == pytest.approx(6.0)
    a.set_speed(3.0, 4.0)  # DO_CHANGE_SPEED as a command (the sim autopilot's path)
    fl, _ = a.update(3.0, (6, 0, 5), 0.0, True)
    assert fl.pos[0] == pytest.approx(6.0) and fl.vel[0] == pytest.approx(4.0)  # no jump, new speed
    fl, _ = a.update(4.0, (10, 0, 5), 0.0, True)
    assert fl.pos[0] == pytest.approx(10.0)


def test_mode_rules():
    ok = dict(airborne=False, armed=False, mission_items=0, first_nav=None)
    assert check_mode_change(4, **ok) == (CopterMode.GUIDED, "")
    assert check_mode_change(3, **ok)[1] == "no mission"
    assert check_mode_change(3, **{**ok, "armed": True, "mission_items": 2, "first_nav": 16})[1] == \
        "Missing Takeoff Cmd"
    assert check_mode_change(6, **ok)[0] is None  # RTL on the ground
    assert check_mode_change(0, **{**ok, "airborne": True, "armed": True})[0] is None
    assert check_mode_change(99, **ok)[0] is None and check_mode_change(4.5, **ok)[0] is None
    assert check_mode_change(math.inf, **ok)[0] is None and check_mode_change(2, **ok)[0] is None
    assert I.capture_id(I.capture_params(5)) == 5
