"""The trajectory flown as a waypoint mission in AUTO (edge.vehicle.auto_flight, MavlinkDriver flight="auto").

Pure parts by hand (items, resume point, speed law), then the driver against the sim autopilot
over real MAVLink on loopback: upload by the mission protocol, AUTO at the start time, formation
speed corrections, every capture, GUIDED hold at the end; a pilot's mode switch in AUTO is
reported and not fought, and resume goes back to AUTO from the right item.
"""

from __future__ import annotations

import math
import time

import pymap3d
import pytest

pytest.importorskip("pymavlink", reason="needs the 'mavlink' extra")

from edge.vehicle.apm import items as AI  # noqa: E402
from edge.vehicle.auto_flight import autopilot_mission, resume_item, speed_correction  # noqa: E402
from edge.vehicle.follower import Follower  # noqa: E402
from edge.vehicle.mavlink import CopterMode, MavlinkDriver, MavlinkParams  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402
from protocol.messages import Mode  # noqa: E402
from tests.edge.vehicle.test_mavlink import HOME, fly, free_udp_port, trajectory  # noqa: E402

HOME_LLA = (21.0278, 105.8342, 12.0)


def test_items_put_every_waypoint_where_the_trajectory_has_it_about_the_autopilots_home():
    traj = trajectory(HOME[2] + 5.0)
    plan = autopilot_mission(traj, HOME, HOME_LLA)
    cmds = [it.command for it in plan.items]
    assert cmds[1] == AI.MAV_CMD_NAV_TAKEOFF and AI.MAV_CMD_NAV_RETURN_TO_LAUNCH not in cmds  # AUTO holds at the end
    assert [it.seq for it in plan.items] == list(range(len(plan.items)))
    assert len(plan.waypoint_seq) == len(traj.waypoints)
    for seq, w in zip(plan.waypoint_seq, traj.waypoints):
        it = plan.items[seq]
        assert it.command == AI.MAV_CMD_NAV_WAYPOINT and it.frame == AI.MAV_FRAME_GLOBAL_RELATIVE_ALT
        assert it.z == pytest.approx(w.pos[2] - HOME[2])  # relative altitude: above home
        e, n, _ = pymap3d.geodetic2enu(it.x / 1e7, it.y / 1e7, HOME_LLA[2], *HOME_LLA)
        assert (e + HOME[0], n + HOME[1]) == pytest.approx(w.pos[:2], abs=0.02)  # 1e-7 degree ~ 1 cm
    assert set(plan.capture_seq) == {11, 12, 13}
    for cid, seq in plan.capture_seq.items():  # MISSION_ITEM_INT: param5 = x (1 shoot), param6 = y (the id)
        it = plan.items[seq]
        assert it.command == AI.MAV_CMD_DO_DIGICAM_CONTROL and (it.x, it.y) == (1, cid)
    speeds = [it.param2 for it in plan.items if it.command == AI.MAV_CMD_DO_CHANGE_SPEED]
    assert speeds[0] == pytest.approx(1.0)  # 4 m in 4 s
    assert resume_item(plan, -1) == plan.waypoint_seq[0] + 1 and resume_item(plan, 1) == plan.waypoint_seq[1] + 1
    assert resume_item(plan, 99) <= len(plan.items) - 1
    with pytest.raises(ValueError):
        autopilot_mission(traj, HOME, (math.nan, 0.0, 0.0))


def test_speed_law_closes_the_along_track_error_only():
    v = (2.0, 0.0, 0.0)
    assert speed_correction((0, 0, 0), (0, 0, 0), v) == pytest.approx(2.0)
    assert speed_correction((-1, 0, 0), (0, 0, 0), v, gain=0.5) == pytest.approx(2.5)  # behind: faster
    assert speed_correction((1, 0, 0), (0, 0, 0), v, gain=0.5) == pytest.approx(1.5)  # ahead: slower
    assert speed_correction((0, 3, 0), (0, 0, 0), v) == pytest.approx(2.0)  # across track: not by speed
    assert speed_correction((50, 0, 0), (0, 0, 0), v) == pytest.approx(0.2)  # bounded below
    assert speed_correction((-50, 0, 0), (0, 0, 0), v) == pytest.approx(5.0)  # and above
    assert speed_correction((0, 0, 0), (0, 0, 0), (0.0, 0.0, 0.0)) is None  # the reference rests
    assert speed_correction((math.nan, 0, 0), (0, 0, 0), v) is None


@pytest.fixture
def auto_link():
    port = free_udp_port()
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", home=HOME,
                        params=MavlinkParams(flight="auto", heartbeat_timeout_s=1.5))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, home=HOME, speed=4.0).start()  # 4x, not 8x: a loaded CI machine lags the 8x clock
    try:
        drv.wait_heartbeat(5.0)
        yield drv, veh
    finally:
        drv.close()
        veh.close()


def test_auto_flies_the_trajectory_in_time_with_every_capture(auto_link):
    drv, veh = auto_link
    drv.takeoff(5.0)
    fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
    traj = trajectory(HOME[2] + 5.0)
    drv.upload(traj)
    ref = Follower(traj)
    drv.start(veh.clock.now() + 1.0)
    assert len(veh.missions.mission()) == len(drv._auto_plan.items)  # uploaded by the mission protocol
    modes, errors = set(), []

    def watch(s):
        modes.add(veh.custom_mode)
        if s.mode == Mode.MISSION and 0.0 < s.progress < 1.0 and veh.custom_mode == CopterMode.AUTO:
            q = veh.sim.state()
            errors.append(math.dist(q.pos, ref.reference(s.progress * ref.duration + q.t - s.t)[0]))

    events = fly(drv, veh, lambda s: s.mode == Mode.HOLD and s.progress == 1.0, 30.0, watch)
    assert CopterMode.AUTO in modes and veh.reached  # flown by the autopilot's mission (MISSION_ITEM_REACHED)
    assert [e.capture_id for e in events] == [11, 12, 13]
    assert sorted(set(veh.shots)) == [11, 12, 13]  # the autopilot's own DO_DIGICAM_CONTROL items
    assert len(errors) > 10 and max(errors) < 1.0  # in time: the plan's speeds plus the corrections
    assert drv.speed_commands > 0 and not drv.auto_errors and not drv.external_modes
    end = time.monotonic() + 5.0
    while veh.custom_mode != CopterMode.GUIDED and time.monotonic() < end:  # holds at the end in GUIDED
        drv.step(veh.clock.now())
        time.sleep(0.01)
    assert veh.custom_mode == CopterMode.GUIDED and drv.state().mode == Mode.HOLD


def test_a_pilot_switch_in_auto_is_reported_not_fought_and_resume_goes_back_to_auto(auto_link):
    drv, veh = auto_link
    drv.takeoff(5.0)
    fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
    drv.upload(trajectory(HOME[2] + 5.0))
    drv.start()
    events = fly(drv, veh, lambda s: veh.custom_mode == CopterMode.AUTO and s.progress > 0.3, 20.0)
    veh.pilot_mode(CopterMode.LOITER)
    events += fly(drv, veh, lambda s: drv.external_modes == ["LOITER"], 5.0)
    st = drv.state()
    assert st.mode == Mode.HOLD and st.progress < 1.0  # paused where the pilot took it
    sent, targets = drv.speed_commands, drv.targets_sent
    clock_end = veh.clock.now() + 2.0
    while veh.clock.now() < clock_end:
        events += drv.step(veh.clock.now())
        time.sleep(0.01)
    assert drv.speed_commands == sent and drv.targets_sent == targets  # not fighting the pilot
    assert veh.custom_mode == CopterMode.LOITER and drv.state().progress == st.progress
    drv.resume()  # back to GUIDED, to the paused point, then AUTO from the next item
    events += fly(drv, veh, lambda s: s.mode == Mode.HOLD and s.progress == 1.0, 30.0)
    assert [e.capture_id for e in events] == [11, 12, 13]
    assert veh.reached and drv.external_modes == ["LOITER"] and not drv.auto_errors
