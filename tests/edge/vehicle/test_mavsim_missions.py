"""The sim autopilot takes the mission items and frames ArduCopter's firmware takes, and flies them.

Uploads and refusals through a real pymavlink session against the sim on loopback UDP; how AUTO walks
the new items (LOITER_TIME's hold, DO_JUMP's count, the items it stores and skips) on the pure
executor, and one mission with a jump flown by the sim. Waits bound a hang, they do not measure speed.
"""

from __future__ import annotations

import math
import socket
import time

import pytest

pytest.importorskip("pymavlink", reason="the sim autopilot needs the 'mavlink' extra")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.geometry import ardupilot_items as AI  # noqa: E402
from edge.vehicle.apm import missions as W  # noqa: E402
from edge.vehicle.apm.auto import AutoMission  # noqa: E402
from edge.vehicle.apm.missions import PlanItem  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402
from tests.edge.vehicle.test_mavsim_firmware import Gcs  # noqa: E402


@pytest.fixture
def session():
    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=4.0).start()
    try:
        gcs.wait("HEARTBEAT", limit_s=10)
        gcs.beat()
        yield gcs, veh
    finally:
        gcs.close()
        veh.close()


def _point(veh: MavlinkSimVehicle, e: float, n: float) -> tuple[int, int]:
    lat, lon, _ = veh.enu_to_lla((e, n, 0.0))
    return round(lat * 1e7), round(lon * 1e7)


def upload(gcs: Gcs, items: list[tuple], limit_s: float = 20.0):
    """Upload ``items`` (frame, command, p1..p4, x, y, z) after a home item; the final MISSION_ACK."""
    rows = [(0, AI.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, 0, 0, 0.0), *items]
    gcs.m.mav.mission_count_send(1, 1, len(rows), M.MAV_MISSION_TYPE_MISSION)
    while True:
        msg = _next(gcs, limit_s)
        if msg.get_type() == "MISSION_ACK":
            return msg
        f, c, p1, p2, p3, p4, x, y, z = rows[msg.seq]
        gcs.m.mav.mission_item_int_send(1, 1, msg.seq, f, c, 0, 1, p1, p2, p3, p4, x, y, z,
                                        M.MAV_MISSION_TYPE_MISSION)


def _next(gcs: Gcs, limit_s: float):
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        msg = gcs.recv()
        if msg is not None and msg.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"):
            return msg
    raise TimeoutError("no mission reply")


#: every mission command ArduCopter's firmware took that the sim used to refuse (frame 3 unless said)
FIRMWARE_ITEMS = [
    (W.MAV_CMD_NAV_LOITER_UNLIM, 0, 0, 0, math.nan, True),
    (W.MAV_CMD_NAV_LOITER_TURNS, 2, 0, 5, 0, True),
    (W.MAV_CMD_NAV_LOITER_TIME, 3, 0, 0, 0, True),
    (W.MAV_CMD_NAV_SPLINE_WAYPOINT, 0, 0, 0, 0, True),
    (W.MAV_CMD_NAV_DELAY, 2, -1, -1, -1, False),
    (W.MAV_CMD_CONDITION_DELAY, 2, 0, 0, 0, False),
    (W.MAV_CMD_CONDITION_DISTANCE, 5, 0, 0, 0, False),
    (W.MAV_CMD_DO_JUMP, 1, 0, 0, 0, False),
    (W.MAV_CMD_DO_SET_SERVO, 9, 1500, 0, 0, False),
    (W.MAV_CMD_DO_LAND_START, 0, 0, 0, 0, False),
    (W.MAV_CMD_DO_SET_ROI, 0, 0, 0, 0, True),
    (W.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, True),
    (W.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 0, False),
]


def test_the_items_and_frame_arducopter_accepts_are_stored_and_downloaded(session):
    gcs, veh = session
    x, y = _point(veh, 10.0, 5.0)
    rows = [(3, c, p1, p2, p3, p4, x if pos else 0, y if pos else 0, 6.0 if pos else 0.0)
            for c, p1, p2, p3, p4, pos in FIRMWARE_ITEMS]
    rows.append((AI.MAV_FRAME_MISSION, AI.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, x, y, veh.home_lla[2] + 6.0))
    ack = upload(gcs, rows)
    assert ack.type == M.MAV_MISSION_ACCEPTED, ack
    stored = veh.missions.mission()
    assert [it.command for it in stored[1:]] == [r[1] for r in rows]
    assert stored[-1].frame == AI.MAV_FRAME_MISSION
    e, n, u = veh.item_enu(stored[-1])  # frame 2: altitude above sea level, as MAV_FRAME_GLOBAL
    assert abs(e - 10.0) < 0.05 and abs(n - 5.0) < 0.05 and abs(u - 6.0) < 0.05
    gcs.m.mav.mission_request_list_send(1, 1, M.MAV_MISSION_TYPE_MISSION)
    assert gcs.wait("MISSION_COUNT", limit_s=10).count == len(rows) + 1
    gcs.m.mav.mission_request_int_send(1, 1, 8, M.MAV_MISSION_TYPE_MISSION)
    back = gcs.wait("MISSION_ITEM_INT", lambda m: m.seq == 8, limit_s=10)
    assert back.command == W.MAV_CMD_DO_JUMP and back.param1 == 1


def test_a_waypoint_with_a_nan_hold_time_is_refused_with_invalid_param1(session):
    gcs, veh = session
    x, y = _point(veh, 3.0, 0.0)
    ack = upload(gcs, [(3, AI.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 5.0),
                       (3, AI.MAV_CMD_NAV_WAYPOINT, math.nan, 0, 0, 0, x, y, 5.0)])
    assert ack.type == M.MAV_MISSION_INVALID_PARAM1
    assert veh.missions.mission() == []  # the old (empty) mission is kept
    ack = upload(gcs, [(3, AI.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, math.nan, x, y, 5.0)])  # NaN yaw is fine
    assert ack.type == M.MAV_MISSION_ACCEPTED


# ---------------------------------------------------------------------------------- how AUTO walks them
HOME = (0.0, 0.0, 0.0)


def _item(seq: int, cmd: int, p1: float = 0.0, p2: float = 0.0, p3: float = 0.0, e: float = 0.0) -> PlanItem:
    return PlanItem(seq, 3, cmd, param1=p1, param2=p2, param3=p3, x=int(e * 1000) + 1, y=1, z=5.0)


def _walk(items: list[PlanItem], limit_s: float = 120.0, dt: float = 0.05):
    """Walk ``items`` with the vehicle on its carrot: (sim time, reached seqs, [(t, current)])."""
    to_enu = lambda it: ((it.x - 1) / 1000.0, 0.0, it.z)  # noqa: E731
    a = AutoMission(items, to_enu, HOME, speed=5.0, radius=0.5, min_leg_s=0.0)
    t, pos, reached, current = 0.0, (0.0, 0.0, 5.0), [], []
    while not a.done and t < limit_s:
        fl, ev = a.update(t, pos, 0.0, True)
        reached += [v for k, v in ev if k == "reached"]
        current += [(t, v) for k, v in ev if k == "current"]
        if fl.kind in ("goto", "hold"):
            pos = fl.pos
        t += dt
    return t, reached, current, a


def test_loiter_time_holds_for_its_time_and_nav_delay_waits_where_it_is():
    home = _item(0, AI.MAV_CMD_NAV_WAYPOINT)
    base, _, _, _ = _walk([home, _item(1, AI.MAV_CMD_NAV_WAYPOINT, e=10), _item(2, AI.MAV_CMD_NAV_WAYPOINT, e=20)])
    t, reached, _, _ = _walk([home, _item(1, W.MAV_CMD_NAV_LOITER_TIME, p1=6.0, e=10),
                              _item(2, AI.MAV_CMD_NAV_WAYPOINT, e=20)])
    assert reached == [1, 2] and 5.5 < t - base < 6.5
    t, reached, _, _ = _walk([home, _item(1, AI.MAV_CMD_NAV_WAYPOINT, e=10), _item(2, W.MAV_CMD_NAV_DELAY, p1=4.0),
                              _item(3, AI.MAV_CMD_NAV_WAYPOINT, e=20)])
    assert reached == [1, 2, 3] and 3.5 < t - base < 4.5
    turns = _walk([home, _item(1, W.MAV_CMD_NAV_LOITER_TURNS, p1=1.0, p3=5.0, e=10),
                   _item(2, AI.MAV_CMD_NAV_WAYPOINT, e=20)])[0]
    assert abs((turns - base) - 2 * math.pi * 5.0 / 5.0) < 0.5  # one 5 m circle at 5 m/s


def test_do_jump_repeats_its_count_and_other_items_are_skipped():
    home = _item(0, AI.MAV_CMD_NAV_WAYPOINT)
    items = [home, _item(1, AI.MAV_CMD_NAV_WAYPOINT, e=5), _item(2, AI.MAV_CMD_NAV_WAYPOINT, e=10),
             _item(3, W.MAV_CMD_DO_SET_SERVO, 9, 1500), _item(4, W.MAV_CMD_DO_JUMP, p1=1, p2=2),
             _item(5, W.MAV_CMD_CONDITION_DELAY, 3), _item(6, W.MAV_CMD_DO_SET_ROI_LOCATION, e=3),
             _item(7, W.MAV_CMD_IMAGE_START_CAPTURE, p3=1), _item(8, AI.MAV_CMD_NAV_WAYPOINT, e=15)]
    _, reached, current, a = _walk(items)
    assert reached == [1, 2, 1, 2, 1, 2, 8] and a.jumps == 2 and a.done
    assert [c for _, c in current].count(1) == 3
    forever = [home, _item(1, AI.MAV_CMD_NAV_WAYPOINT, e=5), _item(2, AI.MAV_CMD_NAV_WAYPOINT, e=10),
               _item(3, W.MAV_CMD_DO_JUMP, p1=1, p2=-1)]
    _, reached, _, a = _walk(forever, limit_s=30.0)
    assert not a.done and a.jumps > 5  # -1: for ever
    t, reached, _, a = _walk([home, _item(1, W.MAV_CMD_NAV_LOITER_UNLIM, e=5)], limit_s=20.0)
    assert not a.done and reached == []  # LOITER_UNLIM holds until told otherwise


def test_the_sim_flies_a_jump_and_a_loiter_time_and_reports_each_item_reached(session):
    gcs, veh = session
    a, b = _point(veh, 4.0, 0.0), _point(veh, 4.0, 4.0)
    ack = upload(gcs, [(3, AI.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 4.0),
                       (3, AI.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, *a, 4.0),
                       (3, W.MAV_CMD_NAV_LOITER_TIME, 2, 0, 0, 0, *b, 4.0),
                       (3, W.MAV_CMD_DO_JUMP, 2, 1, 0, 0, 0, 0, 0.0),
                       (3, W.MAV_CMD_DO_SET_SERVO, 9, 1500, 0, 0, 0, 0, 0.0),
                       (3, AI.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, 0, 0, 0.0)])
    assert ack.type == M.MAV_MISSION_ACCEPTED
    assert gcs.mode(4) == M.MAV_RESULT_ACCEPTED  # GUIDED
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.mode(3) == M.MAV_RESULT_ACCEPTED  # AUTO: takes off from the ground
    gcs.wait("MISSION_ITEM_REACHED", lambda r: r.seq == 6, limit_s=120)
    assert veh.reached[:6] == [1, 2, 3, 2, 3, 6], veh.reached
    assert not veh.errors


# ---------------------------------------------------------------------------------- transfer quirks
def test_downloads_as_the_firmware_nan_yaw_as_zero_home_first_and_rtl_in_frame_0(session):
    gcs, veh = session
    a = _point(veh, 4.0, 0.0)
    ack = upload(gcs, [(3, AI.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 4.0),
                       (3, AI.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, math.nan, *a, 4.0),
                       (3, AI.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0.0)])
    assert ack.type == M.MAV_MISSION_ACCEPTED
    assert math.isnan(veh.missions.mission()[2].param4)  # stored as sent
    got = {}
    for seq in range(4):
        gcs.m.mav.mission_request_int_send(1, 1, seq, M.MAV_MISSION_TYPE_MISSION)
        got[seq] = gcs.wait("MISSION_ITEM_INT", lambda m, s=seq: m.seq == s, limit_s=10)
    lat, lon, alt = veh.home_lla
    assert (got[0].x, got[0].y) == (round(lat * 1e7), round(lon * 1e7)) and got[0].z == pytest.approx(alt, abs=0.01)
    assert got[0].frame == AI.MAV_FRAME_GLOBAL  # item 0: the real home, above sea level
    assert got[1].param4 == 0.0 and got[2].param4 == 0.0  # NaN yaw comes back as 0.0
    assert got[3].command == AI.MAV_CMD_NAV_RETURN_TO_LAUNCH and got[3].frame == AI.MAV_FRAME_GLOBAL


def test_legacy_mission_request_is_answered_with_mission_item_int_and_the_driver_completes():
    from edge.vehicle.mavlink import MavlinkDriver, MavlinkParams
    from protocol.messages import Mode
    from tests.edge.vehicle.test_mavlink import HOME, fly, trajectory

    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=4.0, legacy_mission_request=True).start()
    try:
        gcs.wait("HEARTBEAT", limit_s=10)
        gcs.m.mav.mission_count_send(1, 1, 2, M.MAV_MISSION_TYPE_MISSION)
        req = _next(gcs, 10)
        assert req.get_type() == "MISSION_REQUEST" and req.seq == 0  # not MISSION_REQUEST_INT
        gcs.m.mav.mission_item_int_send(1, 1, 0, 0, 16, 0, 1, 0, 0, 0, 0, 0, 0, 0.0, 0)
        req = _next(gcs, 10)
        assert req.get_type() == "MISSION_REQUEST" and req.seq == 1  # still the legacy request
        x, y = _point(veh, 2.0, 0.0)
        gcs.m.mav.mission_item_int_send(1, 1, 1, 3, 16, 0, 1, 0, 0, 0, 0, x, y, 3.0, 0)
        assert _next(gcs, 10).type == M.MAV_MISSION_ACCEPTED
        assert veh.missions.mission()[1].x == x
    finally:
        gcs.close()
        veh.close()
    port = free_port(socket.SOCK_DGRAM)
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", home=HOME, params=MavlinkParams(flight="auto"))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, home=HOME, speed=4.0, legacy_mission_request=True).start()
    try:
        drv.wait_heartbeat(5.0)
        drv.takeoff(5.0)
        fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
        drv.upload(trajectory(HOME[2] + 5.0))
        drv.start(veh.clock.now() + 1.0)
        fly(drv, veh, lambda s: s.mode == Mode.MISSION, 10.0)
        assert len(veh.missions.mission()) == len(drv.auto.plan.items) and not drv.auto.errors
    finally:
        drv.close()
        veh.close()


# ---------------------------------------------------------------------------------- LOITER without RC
def test_loiter_without_rc_descends_at_the_throttle_down_rate_and_lands(session):
    from edge.vehicle.apm.modes import PILOT_DESCENT_MS

    gcs, veh = session
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 100_000) == 0
    assert gcs.mode(4) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 10.0) == M.MAV_RESULT_ACCEPTED
    gcs.wait("GLOBAL_POSITION_INT", lambda g: g.relative_alt > 9_700, limit_s=60)
    x0, y0, _ = veh.sim.state().pos
    assert gcs.mode(5) == M.MAV_RESULT_ACCEPTED  # LOITER, no RC: the throttle stick rests at the bottom
    fast = gcs.wait("GLOBAL_POSITION_INT", lambda g: g.vz > 150, limit_s=30)  # NED: down, cm/s
    assert fast.relative_alt > 2_000  # descending well above the ground
    vz = [gcs.wait("GLOBAL_POSITION_INT", limit_s=5).vz for _ in range(4)]
    assert max(vz) <= PILOT_DESCENT_MS * 100 * 1.3 and min(vz) > 100, vz
    gcs.wait("HEARTBEAT", lambda h: not h.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, limit_s=60)  # landed, disarmed
    x, y, z = veh.sim.state().pos
    assert math.hypot(x - x0, y - y0) < 1.0 and z < 0.3  # straight down where the pilot left it
    assert veh.custom_mode == 5 and not veh.errors


# ---------------------------------------------------------------------------------- the pilot's takeover
def pilot_switch(veh: MavlinkSimVehicle, mode: int) -> None:
    """A second MAVLink link (a pilot's ground station) sends DO_SET_MODE straight to the sim autopilot."""
    from edge.vehicle.mavlink import open_connection

    port = veh._conn.port.getsockname()[1]
    pilot = open_connection(f"udpout:127.0.0.1:{port}", 250, M.MAV_COMP_ID_MISSIONPLANNER)
    try:
        for _ in range(3):  # UDP: say it a few times (a repeated mode change is harmless)
            pilot.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode,
                                        0, 0, 0, 0, 0)
            time.sleep(0.05)
    finally:
        pilot.close()


def test_a_pilot_switch_to_loiter_is_reported_as_loiter_and_the_descent_never_as_hold():
    from edge.vehicle.mavlink import MavlinkDriver, MavlinkParams
    from protocol.messages import Mode
    from tests.edge.vehicle.test_mavlink import HOME, fly

    port = free_port(socket.SOCK_DGRAM)
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", home=HOME, params=MavlinkParams(heartbeat_timeout_s=1.5))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, home=HOME, speed=4.0).start()
    try:
        drv.wait_heartbeat(5.0)
        drv.takeoff(10.0)
        fly(drv, veh, lambda s: s.mode == Mode.HOLD and s.pos[2] > HOME[2] + 9.5, 30.0)
        assert drv.readiness().mode == "GUIDED" and not drv.readiness().external
        pilot_switch(veh, 5)  # LOITER
        fly(drv, veh, lambda s: s.mode == Mode.PILOT, 10.0)
        seen = []
        fly(drv, veh, lambda s: seen.append(s) or s.vel[2] < -1.5, 10.0)
        st, ap = seen[-1], drv.readiness()
        assert st.mode == Mode.PILOT and st.vel[2] < -1.5, st  # what it does: descending, not "hold"
        assert ap.mode == "LOITER" and ap.external and drv.external_modes == ["LOITER"]
        assert all(s.mode != Mode.HOLD for s in seen)
        fly(drv, veh, lambda s: s.mode == Mode.LANDED, 30.0)  # it lands, as the firmware does
        assert not drv.state().armed and drv.state().pos[2] < HOME[2] + 0.5
    finally:
        drv.close()
        veh.close()


def test_the_command_line_offers_the_legacy_mission_request():
    from edge.vehicle.mavsim import build_parser

    assert build_parser().parse_args(["--uav", "1", "--legacy-mission-request"]).legacy_mission_request
    assert not build_parser().parse_args(["--uav", "1"]).legacy_mission_request


def test_with_the_pilots_rc_sticks_centred_loiter_holds_its_altitude():
    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=4.0, rc_centred=True).start()
    try:
        gcs.wait("HEARTBEAT", limit_s=10)
        assert gcs.mode(4) == M.MAV_RESULT_ACCEPTED
        assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert gcs.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 6.0) == M.MAV_RESULT_ACCEPTED
        end = time.monotonic() + 30
        while veh.sim.state().pos[2] < 5.7 and time.monotonic() < end:
            time.sleep(0.05)
        assert gcs.mode(5) == M.MAV_RESULT_ACCEPTED
        t_end = veh.clock.now() + 4.0
        while veh.clock.now() < t_end:
            time.sleep(0.05)
        assert abs(veh.sim.state().pos[2] - 6.0) < 0.5 and veh.armed
    finally:
        gcs.close()
        veh.close()


def _fly_to_a_waypoint_and_land(late_s: float) -> tuple[list[float], tuple[float, float, float]]:
    """AUTO: take off, one waypoint 10 m east, land; one pass of the sim ``late_s`` simulated s late when the
    vehicle is 4 m short of the waypoint. The vehicle's easting from then on and where it landed."""
    from edge.clock import SimClock

    port = free_port(socket.SOCK_DGRAM)
    gcs = Gcs(port)
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, speed=4.0)
    ahead = [0.0]  # wall seconds the clock jumps: the next pass comes that much late
    real = veh.clock
    veh.clock = SimClock(real.epoch, real.speed, time_fn=lambda: time.time() + ahead[0])
    veh.start()
    try:
        gcs.wait("HEARTBEAT", limit_s=10)
        gcs.beat()
        ack = upload(gcs, [(3, AI.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 4.0),
                           (3, AI.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, *_point(veh, 10.0, 0.0), 4.0),
                           (3, AI.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, 0, 0, 0.0)])
        assert ack.type == M.MAV_MISSION_ACCEPTED
        assert gcs.mode(4) == M.MAV_RESULT_ACCEPTED  # GUIDED
        assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert gcs.mode(3) == M.MAV_RESULT_ACCEPTED  # AUTO
        end = time.monotonic() + 60
        while veh.sim.state().pos[0] < 6.0:
            assert time.monotonic() < end, veh.sim.state().pos
            time.sleep(0.002)
        ahead[0] = late_s / real.speed
        east = []
        while veh.sim.state().pos[2] > 0.5:
            assert time.monotonic() < end, veh.sim.state().pos
            east.append(veh.sim.state().pos[0])
            time.sleep(0.002)
        assert not veh.errors, veh.errors
        return east, veh.sim.state().pos
    finally:
        gcs.close()
        veh.close()


def test_a_late_pass_flies_the_mission_as_an_on_time_one():
    """A pass of the sim 2.5 simulated s late (its process starved of CPU at an accelerated clock) flies the
    mission as the firmware would, whose mission logic runs every loop: the vehicle lands where it lands
    without the late pass. Before, the late pass carried the leg's moving target on for the whole gap and
    the vehicle landed 3 m further on."""
    _, on_time = _fly_to_a_waypoint_and_land(0.0)
    east, late = _fly_to_a_waypoint_and_land(2.5)
    assert east[0] < 8.0, east[0]  # the late pass came before the waypoint's 2 m radius
    assert math.dist(on_time[:2], late[:2]) < 1.0, (on_time, late)
