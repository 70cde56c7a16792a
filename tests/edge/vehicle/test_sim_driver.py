"""SimDriver behind the driver interface: modes, commands, captures, RTL, offsets."""

from __future__ import annotations

import math

import pytest

from edge.vehicle.driver import DriverState, VehicleDriver
from edge.vehicle.quadrotor import DisturbanceParams
from edge.vehicle.sim import SimDriver, SimParams
from protocol.messages import Mode, Trajectory, VehicleState, Waypoint

WINDY = SimParams(disturbance=DisturbanceParams.moderate())


def run_until(d: SimDriver, cond, limit: float, dt: float = 0.1):
    events = []
    end = d.t + limit
    while not cond(d) and d.t < end:
        events += d.step(d.t + dt)
    assert cond(d), f"condition not reached within {limit} s (mode {d.mode})"
    return events


def line_traj(uav=1, start=(0.0, 0.0, 10.0), n=5, spacing=4.0, speed=2.0, captures=True, z=10.0):
    wps = []
    for i in range(n):
        p = (start[0] + i * spacing, start[1], z)
        wps.append(Waypoint(t=i * spacing / speed, pos=p, capture_id=(100 + i) if captures else None))
    return Trajectory(uav=uav, waypoints=wps)


def airborne(params=WINDY, seed=1, alt=10.0, home=(0.0, 0.0, 0.0)) -> SimDriver:
    d = SimDriver(1, params, seed=seed, home=home)
    d.takeoff(alt)
    run_until(d, lambda d: d.mode == Mode.HOLD, 20)
    return d


def test_is_a_vehicle_driver_and_starts_idle_at_home():
    d = SimDriver(3, home=(5.0, -2.0, 1.0))
    assert isinstance(d, VehicleDriver)
    s = d.state()
    assert isinstance(s, DriverState)
    assert s.mode == Mode.IDLE and not s.armed and s.pos == (5.0, -2.0, 1.0) and s.wp_index == -1
    d.step(5.0)  # idle: nothing moves, time advances
    assert d.state().pos == (5.0, -2.0, 1.0) and d.t == pytest.approx(5.0)


@pytest.mark.parametrize("cmd", ["start", "land", "hold", "resume", "return_to_launch"])
def test_commands_invalid_on_the_ground_raise(cmd):
    d = SimDriver(1)
    with pytest.raises(ValueError, match="mode idle"):
        getattr(d, cmd)()


def test_takeoff_to_hold_and_invalid_commands_airborne():
    d = SimDriver(1, WINDY, seed=2)
    d.takeoff(8.0)
    assert d.mode == Mode.TAKEOFF and d.armed
    run_until(d, lambda d: d.mode == Mode.HOLD, 20)
    assert d.state().pos[2] == pytest.approx(8.0, abs=0.2)
    with pytest.raises(ValueError, match="take off"):
        d.takeoff(5.0)
    with pytest.raises(ValueError, match="no trajectory"):
        d.start()
    with pytest.raises(ValueError, match="no paused mission"):
        d.resume()
    with pytest.raises(ValueError):
        SimDriver(1).takeoff(math.nan)


def test_upload_validation():
    d = SimDriver(1)
    with pytest.raises(ValueError, match="UAV 2"):
        d.upload(line_traj(uav=2))
    with pytest.raises(ValueError, match="below"):
        d.upload(line_traj(z=0.2))
    with pytest.raises(ValueError, match="limits"):
        d.upload(line_traj(speed=40.0))
    with pytest.raises(ValueError):
        d.upload({"uav": 1})  # type: ignore[arg-type]
    d.upload(line_traj())  # fine on the ground


def test_mission_flies_transit_then_track_fires_each_capture_once_and_holds_at_end():
    d = airborne()
    traj = line_traj(start=(10.0, 5.0, 10.0))
    d.upload(traj)
    d.start()
    assert d.mode == Mode.MISSION and d._phase == "transit"  # 11 m from the first waypoint
    events = run_until(d, lambda d: d.mode == Mode.HOLD, 60)
    ids = [e.capture_id for e in events]
    assert ids == [100, 101, 102, 103, 104]
    for e, w in zip(events, traj.waypoints):
        assert math.dist(e.pos, w.pos) < 0.5  # the vehicle was at the capture point
    s = d.state()
    assert s.captures == 5 and s.progress == 1.0 and s.wp_index == 4
    assert math.dist(s.pos, traj.waypoints[-1].pos) < 0.3
    assert d.step(d.t + 5.0) == []  # nothing fires again


def test_start_time_in_the_future_waits_at_first_waypoint():
    d = airborne()
    d.upload(line_traj(start=(0.0, 0.0, 10.0)))
    t0 = d.t + 5.0
    d.start(t0)
    d.step(t0 - 0.5)
    s = d.state()
    assert s.mode == Mode.MISSION and s.progress == 0.0 and s.wp_index == -1
    assert math.dist(s.pos, (0.0, 0.0, 10.0)) < 0.3
    ev = d.step(t0 + 0.05)
    assert [e.capture_id for e in ev] == [100]
    assert d.state().wp_index == 0


def test_hold_pauses_and_resume_continues():
    d = airborne()
    d.upload(line_traj(start=(0.0, 0.0, 10.0), captures=True))
    d.start()
    ev = d.step(d.t + 3.0)  # passes waypoints 0 and 1 (t = 0, 2)
    assert [e.capture_id for e in ev] == [100, 101]
    d.hold()
    assert d.mode == Mode.HOLD
    p_hold = d.state().pos
    prog = d.state().progress
    assert d.step(d.t + 5.0) == []  # paused: no captures, no progress
    assert d.state().progress == pytest.approx(prog)
    assert math.dist(d.state().pos, p_hold) < 1.0
    d.resume()
    assert d.mode == Mode.MISSION
    ev = run_until(d, lambda d: d.mode == Mode.HOLD, 30)
    assert [e.capture_id for e in ev] == [102, 103, 104]


def test_hold_during_return_to_the_paused_point_resumes_there():
    d = airborne(params=SimParams())
    d.upload(line_traj(start=(0.0, 0.0, 10.0), n=6))
    d.start()
    assert [e.capture_id for e in d.step(d.t + 5.0)] == [100, 101, 102]
    d.hold()
    d.set_reference_offset((0.0, 0.0, 0.0))
    d.quad.s = (d.quad.s[0], d.quad.s[1] + 5.0, *d.quad.s[2:])  # pushed 5 m sideways by a gust
    d.resume()
    assert d._phase == "transit_resume"
    d.step(d.t + 0.5)
    d.hold()  # paused again on the way back
    d.resume()
    assert d._phase == "transit_resume"  # still heading back to the paused point, not the start
    ev = run_until(d, lambda d: d.mode == Mode.HOLD, 40)
    assert [e.capture_id for e in ev] == [103, 104, 105]


def test_upload_clears_a_paused_mission():
    d = airborne(params=SimParams())
    d.upload(line_traj())
    d.start()
    d.step(d.t + 3.0)
    d.hold()
    d.upload(line_traj())
    with pytest.raises(ValueError, match="no paused mission"):
        d.resume()


def test_reference_offset_is_bounded_and_applied():
    d = airborne(params=SimParams())
    d.upload(Trajectory(uav=1, waypoints=[Waypoint(t=0, pos=(0, 0, 10)), Waypoint(t=30, pos=(0, 0.5, 10))]))
    d.start()
    d.set_reference_offset((10.0, 0.0, 0.0))  # bounded to 3 m
    d.step(d.t + 15.0)
    assert d.state().pos[0] == pytest.approx(3.0, abs=0.2)
    with pytest.raises(ValueError):
        d.set_reference_offset((math.nan, 0.0, 0.0))
    with pytest.raises(ValueError):
        d.set_reference_offset((1.0, 2.0))


def test_land_disarms_on_the_ground():
    d = airborne()
    d.land()
    assert d.mode == Mode.LAND
    run_until(d, lambda d: d.mode == Mode.LANDED, 30)
    s = d.state()
    assert not s.armed and s.pos[2] == 0.0 and s.vel == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        d.land()
    d.takeoff(3.0)  # can fly again
    assert d.mode == Mode.TAKEOFF


def test_rtl_returns_home_and_lands():
    d = airborne(home=(2.0, 3.0, 1.0))
    d.upload(line_traj(start=(20.0, 10.0, 12.0), z=12.0))
    d.start()
    run_until(d, lambda d: d.mode == Mode.HOLD, 60)
    d.return_to_launch()
    assert d.mode == Mode.RTL
    max_alt = 0.0

    def landed(d):
        nonlocal max_alt
        max_alt = max(max_alt, d.state().pos[2])
        return d.mode == Mode.LANDED

    run_until(d, landed, 120)
    s = d.state()
    assert math.hypot(s.pos[0] - 2.0, s.pos[1] - 3.0) < 0.5
    assert s.pos[2] == 1.0 and not s.armed
    assert max_alt >= 1.0 + 10.0 - 0.3  # climbed to the return altitude first


def test_same_seed_same_flight_and_state_message():
    a, b = airborne(seed=4), airborne(seed=4)
    a.step(a.t + 3.0)
    b.step(b.t + 3.0)
    assert a.state() == b.state()
    c = airborne(seed=5)
    c.step(c.t + 3.0)
    assert c.state().pos != a.state().pos
    msg = a.state().to_message(uav=1, seq=7, stamp=1.7e9)
    assert isinstance(msg, VehicleState) and msg.mode == Mode.HOLD and msg.seq == 7
    assert -math.pi < msg.att[2] <= math.pi


def test_step_edge_cases_and_close():
    d = SimDriver(1)
    assert d.step(-3.0) == []
    with pytest.raises(ValueError):
        d.step(math.nan)
    d.takeoff(2.0)
    with pytest.raises(ValueError, match="exceeds"):  # airborne: hours in one call is a time mix-up
        d.step(1.0e6)
    d.close()
    with pytest.raises(ValueError, match="closed"):
        d.takeoff(5.0)


@pytest.mark.parametrize("kw", [dict(uav=0), dict(uav=1, physics_hz=50), dict(uav=1, home=(0, 0, math.nan))])
def test_bad_construction_raises(kw):
    with pytest.raises(ValueError):
        SimDriver(**kw)


def test_external_reference_is_flown_in_hold_and_dropped_by_mode_changes():
    d = airborne(params=SimParams())
    target = (4.0, -3.0, 12.0)
    d.set_external_reference(lambda t: (target, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.5))
    d.step(d.t + 8.0)
    s = d.state()
    assert math.dist(s.pos, target) < 0.3 and s.att[2] == pytest.approx(0.5, abs=0.05)
    d.land()  # a mode change drops the hook: after landing and a new takeoff it is not flown again
    run_until(d, lambda d: d.mode == Mode.LANDED, 30)
    ground = d.state().pos
    d.takeoff(6.0)
    run_until(d, lambda d: d.mode == Mode.HOLD, 20)
    d.step(d.t + 3.0)
    assert math.dist(d.state().pos, (ground[0], ground[1], 6.0)) < 0.5 and math.dist(ground[:2], target[:2]) < 0.5
    with pytest.raises(ValueError, match="callable"):
        d.set_external_reference((1.0, 2.0, 3.0))  # type: ignore[arg-type]
    d.set_external_reference(None)
