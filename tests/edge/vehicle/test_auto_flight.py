"""The trajectory flown as a waypoint mission in AUTO (edge.vehicle.auto_flight, MavlinkDriver flight="auto").

Pure parts by hand (items, resume point, speed law), then the driver against the sim autopilot
over real MAVLink on loopback: upload by the mission protocol, AUTO at the start time, formation
speed corrections, every capture, GUIDED hold at the end; a pilot's mode switch in AUTO is
reported and not fought, and resume goes back to AUTO from the right item.
"""

from __future__ import annotations

import math
import threading
import time

import pymap3d
import pytest

pytest.importorskip("pymavlink", reason="needs the 'mavlink' extra")

from edge.geometry import ardupilot_items as AI  # noqa: E402
from edge.vehicle.apm.auto import AutoMission  # noqa: E402
from edge.vehicle.auto_flight import autopilot_mission, decimate, resume_item, speed_correction  # noqa: E402
from edge.vehicle.follower import Follower  # noqa: E402
from edge.vehicle.mavlink import CopterMode, MavlinkDriver, MavlinkParams  # noqa: E402
from edge.vehicle.mavsim import MavlinkSimVehicle  # noqa: E402
from protocol.messages import Mode, Trajectory, Waypoint  # noqa: E402
from tests.edge.vehicle.test_mavlink import HOME, driven, fly, free_udp_port, trajectory  # noqa: E402

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
    # 4x, not 8x: a loaded CI machine lags the 8x clock
    with driven(MavlinkSimVehicle, MavlinkParams(flight="auto", heartbeat_timeout_s=1.5), speed=4.0) as pair:
        yield pair


def test_auto_flies_the_trajectory_in_time_with_every_capture(auto_link):
    drv, veh = auto_link
    drv.takeoff(5.0)
    fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
    traj = trajectory(HOME[2] + 5.0)
    drv.upload(traj)
    ref = Follower(traj)
    drv.start(veh.clock.now() + 1.0)
    assert len(veh.missions.mission()) == len(drv.auto.plan.items)  # uploaded by the mission protocol
    modes, errors = set(), []

    def watch(s):
        modes.add(veh.custom_mode)
        if s.mode == Mode.MISSION and 0.0 < s.progress < 1.0 and veh.custom_mode == CopterMode.AUTO:
            q = veh.sim.state()
            errors.append(math.dist(q.pos, ref.reference(s.progress * ref.duration + q.t - s.t)[0]))

    events = fly(drv, veh, lambda s: s.mode == Mode.HOLD and s.progress == 1.0, 30.0, watch)
    assert CopterMode.AUTO in modes and veh.reached  # flown by the autopilot's mission (MISSION_ITEM_REACHED)
    assert [e.capture_id for e in events] == [11, 12, 13]
    assert len(errors) > 10 and max(errors) < 1.0  # in time: the plan's speeds plus the corrections
    assert drv.auto.speed_commands > 0 and not drv.auto.errors and not drv.external_modes
    end = time.monotonic() + 5.0
    while veh.custom_mode != CopterMode.GUIDED and time.monotonic() < end:  # holds at the end in GUIDED
        drv.step(veh.clock.now())
        time.sleep(0.01)
    assert veh.custom_mode == CopterMode.GUIDED and drv.state().mode == Mode.HOLD
    # GUIDED only once the autopilot reached its last waypoint: its own DO_DIGICAM_CONTROL items all ran
    assert sorted(set(veh.shots)) == [11, 12, 13] and veh.reached[-1] == max(drv.auto.plan.waypoint_seq)


def test_a_pilot_switch_in_auto_is_reported_not_fought_and_resume_goes_back_to_auto(auto_link):
    drv, veh = auto_link
    drv.takeoff(5.0)
    fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
    drv.upload(trajectory(HOME[2] + 5.0))
    ran_on = []  # the thread of the upload and of every mode switch
    for name in ("_upload_plan", "_switch"):
        job = getattr(drv.auto, name)
        setattr(drv.auto, name, lambda *a, job=job: (ran_on.append(threading.current_thread()), job(*a))[1])
    drv.start()
    events = fly(drv, veh, lambda s: veh.custom_mode == CopterMode.AUTO and s.progress > 0.3, 20.0)
    veh.pilot_mode(CopterMode.LOITER)
    events += fly(drv, veh, lambda s: drv.external_modes == ["LOITER"], 5.0)
    st = drv.state()
    assert st.mode == Mode.PILOT and st.progress < 1.0  # paused where the pilot took it, not "hold"
    ap = drv.readiness()
    assert ap.mode == "LOITER" and ap.external
    sent, targets = drv.auto.speed_commands, drv.targets.sent
    clock_end = veh.clock.now() + 0.8  # LOITER without RC descends: resume before it lands
    while veh.clock.now() < clock_end:
        events += drv.step(veh.clock.now())
        time.sleep(0.01)
    assert drv.auto.speed_commands == sent and drv.targets.sent == targets  # not fighting the pilot
    assert veh.sim.state().pos[2] < st.pos[2] - 0.3  # the sticks at rest: it comes down
    assert veh.custom_mode == CopterMode.LOITER and drv.state().progress == st.progress
    drv.resume()  # back to GUIDED, to the paused point, then AUTO from the next item
    events += fly(drv, veh, lambda s: s.mode == Mode.HOLD and s.progress == 1.0, 30.0)
    assert [e.capture_id for e in events] == [11, 12, 13]
    assert veh.reached and drv.external_modes == ["LOITER"] and not drv.auto.errors
    end = time.monotonic() + 10.0
    while veh.custom_mode != CopterMode.GUIDED and time.monotonic() < end:  # the switch back to GUIDED
        drv.step(veh.clock.now())
        time.sleep(0.01)
    assert len(ran_on) >= 4 and len(set(ran_on)) == 1  # upload, AUTO, AUTO again, GUIDED: one worker
    assert ran_on[0] is not threading.current_thread()


# ---------------------------------------------------------------------------------- dense trajectories
def dense(z: float, spacing: float = 0.8, speed: float = 2.0) -> Trajectory:
    """16 m east then 8 m north at ``speed``, a waypoint every ``spacing`` m (the planner's density),
    captures at the corner and the end."""
    x0, y0 = HOME[0], HOME[1]
    pts = [(x0 + k * spacing, y0) for k in range(int(16 / spacing) + 1)]
    pts += [(x0 + 16, y0 + k * spacing) for k in range(1, int(8 / spacing) + 1)]
    wps, t = [], 0.0
    for k, (x, y) in enumerate(pts):
        if k:
            t += math.dist(pts[k - 1], (x, y)) / speed
        cid = 21 if (x, y) == (x0 + 16, y0) else 22 if k == len(pts) - 1 else None
        wps.append(Waypoint(t=t, pos=(x, y, z), yaw=0.0, capture_id=cid))
    return Trajectory(uav=1, waypoints=wps)


def fly_items(items, limit_s: float = 200.0) -> tuple[float, list[int]]:
    """Sim time AUTO (:class:`AutoMission`, ArduCopter's leg timing) takes to walk the mission with the
    vehicle on its carrot, and the shots taken."""
    to_enu = lambda it: tuple(HOME[k] + d for k, d in enumerate(pymap3d.geodetic2enu(
        it.x / 1e7, it.y / 1e7, HOME_LLA[2] + it.z, *HOME_LLA)))
    a = AutoMission(list(items), to_enu, HOME, speed=10.0, radius=0.5)
    t, pos, shots = 0.0, (HOME[0], HOME[1], HOME[2] + 5.0), []
    while not a.done and t < limit_s:
        fl, ev = a.update(t, pos, 0.0, True)
        shots += [v for k, v in ev if k == "shot"]
        if fl.kind in ("goto", "hold"):
            pos = fl.pos
        t += 0.05
    return t, shots


def test_a_dense_mission_is_flown_slowly_as_by_arducopter_and_the_decimated_one_at_plan_speed():
    traj = dense(HOME[2] + 5.0)
    planned = traj.waypoints[-1].t  # 12 s at 2 m/s
    keep = decimate(traj)
    assert keep[0] == 0 and keep[-1] == len(traj.waypoints) - 1 and len(keep) < len(traj.waypoints) / 4
    assert all(traj.waypoints[i].capture_id is None or i in keep for i in range(len(traj.waypoints)))
    for a, b in zip(keep, keep[1:]):  # every dropped waypoint lies on its leg
        for m in range(a + 1, b):
            assert abs(traj.waypoints[m].pos[1] - traj.waypoints[a].pos[1]) < 0.31 or \
                abs(traj.waypoints[m].pos[0] - traj.waypoints[a].pos[0]) < 0.31
    plan = autopilot_mission(traj, HOME, HOME_LLA)
    assert len(set(plan.waypoint_seq)) == len(keep) and len(plan.waypoint_seq) == len(traj.waypoints)
    slow_items = _dense_items(traj)  # one NAV_WAYPOINT per 0.8 m
    assert sum(it.command == AI.MAV_CMD_NAV_WAYPOINT for it in slow_items) == len(traj.waypoints) + 1
    t_slow, _ = fly_items(slow_items)
    t_plan, shots = fly_items(plan.items)
    assert t_slow > 2.5 * planned  # ~0.45 m/s: what ArduCopter does with 0.8 m legs
    assert t_plan < planned + 4.0 and shots == [21, 22]  # the decimated mission keeps the plan's timing
    assert resume_item(plan, 3) == plan.waypoint_seq[0] + 1  # a dropped waypoint resumes after the last kept


def _dense_items(traj: Trajectory):
    """The mission without decimation (every waypoint a NAV_WAYPOINT), as MISSION_ITEM_INT fields."""
    from edge.geometry.waypoint_mission import mission_items
    from edge.vehicle.apm.missions import PlanItem

    origin = pymap3d.enu2geodetic(-HOME[0], -HOME[1], -HOME[2], *HOME_LLA)
    out = []
    for it in mission_items(traj, origin)[:-1]:
        p = it.params
        glob = it.frame in (0, 3)
        out.append(PlanItem(seq=len(out), frame=it.frame, command=it.command, param1=p[0], param2=p[1],
                            param3=p[2], param4=p[3], x=round(p[4] * 1e7) if glob else int(p[4]),
                            y=round(p[5] * 1e7) if glob else int(p[5]), z=p[6] - HOME[2] if it.frame == 3 else p[6]))
    return out


def test_auto_flies_a_dense_trajectory_in_time(auto_link):
    drv, veh = auto_link
    drv.takeoff(5.0)
    fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
    traj = dense(HOME[2] + 5.0)
    drv.upload(traj)
    ref = Follower(traj)
    drv.start(veh.clock.now() + 1.0)
    errors = []

    def watch(s):
        if s.mode == Mode.MISSION and 0.0 < s.progress < 1.0 and veh.custom_mode == CopterMode.AUTO:
            q = veh.sim.state()
            errors.append(math.dist(q.pos, ref.reference(s.progress * ref.duration + q.t - s.t)[0]))

    events = fly(drv, veh, lambda s: s.mode == Mode.HOLD and s.progress == 1.0, 40.0, watch)
    assert [e.capture_id for e in events] == [21, 22]
    assert len(errors) > 10 and max(errors) < 1.5, max(errors, default=None)  # at plan speed, not ~0.5 m/s
    assert not drv.auto.errors


# ---------------------------------------------------------------------------------- progress from the autopilot
def test_the_autopilots_window_bounds_the_clock_between_the_reached_and_the_current_waypoint():
    from edge.vehicle.mavlink.progress import autopilot_window, bounded

    seqs, fr = (3, 5, 5, 8, 10), (0.0, 0.25, 0.5, 0.75, 1.0)  # waypoint 2 was dropped: it shares item 5
    assert autopilot_window(seqs, fr, reached=-1, current=-1) == (0.0, 1.0)  # nothing known: no bound
    assert autopilot_window(seqs, fr, reached=3, current=5) == (0.0, 0.25)
    assert autopilot_window(seqs, fr, reached=5, current=6) == (0.25, 0.75)  # a DO item after it: next NAV
    assert autopilot_window(seqs, fr, reached=10, current=10) == (1.0, 1.0)
    assert autopilot_window(seqs, fr, reached=8, current=4) == (0.75, 0.75)  # never hi < lo
    assert bounded(0.9, (0.0, 0.25), fr) == (1, 0.25)  # the clock ran ahead of a slow autopilot
    assert bounded(0.1, (0.5, 0.75), fr) == (2, 0.5)  # and behind a fast one
    assert bounded(0.6, (0.25, 0.75), fr) == (2, 0.6)


def test_auto_progress_follows_a_slow_autopilot_not_the_edges_clock(monkeypatch):
    """An autopilot flying the mission slower than planned, deaf to speed changes (as ArduCopter flies a dense
    mission): the edge reports where the autopilot is in the trajectory, not where its own clock is."""
    from pymavlink.dialects.v20 import ardupilotmega as M

    from edge.vehicle.mavsim import commands as sim_commands

    monkeypatch.setattr(AutoMission, "_leg_speed", lambda self: 0.3)
    monkeypatch.setitem(sim_commands.COMMANDS, M.MAV_CMD_DO_CHANGE_SPEED, lambda v, c, i: M.MAV_RESULT_ACCEPTED)
    port = free_udp_port()
    drv = MavlinkDriver(1, f"udpin:127.0.0.1:{port}", home=HOME,
                        params=MavlinkParams(flight="auto", heartbeat_timeout_s=1.5, auto_end_wait_s=10.0))
    veh = MavlinkSimVehicle(f"udpout:127.0.0.1:{port}", 1, home=HOME, speed=4.0).start()
    try:
        drv.wait_heartbeat(5.0)
        drv.takeoff(5.0)
        fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
        traj = trajectory(HOME[2] + 5.0)
        drv.upload(traj)
        t0 = veh.clock.now() + 1.0
        drv.start(t0)
        fly(drv, veh, lambda s: veh.custom_mode == CopterMode.AUTO, 10.0)
        seen = []
        fly(drv, veh, lambda s: seen.append(s) or s.t > t0 + traj.waypoints[-1].t + 2.0, 30.0)
        st, ap = seen[-1], drv.mission_progress()
        assert ap is not None and ap.hi <= 0.4 + 1e-9, ap  # flying to waypoint 1 (t = 4 s of 10 s) at most
        assert st.progress <= ap.hi and st.wp_index <= 1, st  # the clock says 1.0; the autopilot does not
        assert veh.sim.state().pos[0] - HOME[0] < 4.0  # and it is right: the vehicle is short of waypoint 1
        assert all(b.progress >= a.progress - 1e-9 for a, b in zip(seen, seen[1:]))  # never backwards
        assert veh.custom_mode == CopterMode.AUTO  # still flying its mission, not cut short to GUIDED
    finally:
        drv.close()
        veh.close()


def test_auto_follows_a_slow_autopilot_to_the_end_and_captures_at_the_points(auto_link, monkeypatch):
    """The autopilot flies slower than the plan (0.5 m/s legs, as ArduCopter flies dense missions): when the edge's
    trajectory clock runs out the edge's mode stays MISSION until the autopilot reports its last waypoint reached,
    and the captures fire where the vehicle is at their points, not when the clock says."""
    leg_speed = AutoMission._leg_speed
    monkeypatch.setattr(AutoMission, "_leg_speed", lambda self: min(leg_speed(self), 0.5))
    drv, veh = auto_link
    drv.takeoff(5.0)
    fly(drv, veh, lambda s: s.mode == Mode.HOLD, 15.0)
    traj = trajectory(HOME[2] + 5.0)
    drv.upload(traj)
    drv.start(veh.clock.now() + 1.0)
    last = max(drv.auto.plan.waypoint_seq)
    seen = []
    events = fly(drv, veh, lambda s: s.mode == Mode.HOLD, 90.0,
                 lambda s: seen.append((drv.mission.done, s.mode, drv.tel.reached_seq)))
    after_clock = [(mode, reached) for done, mode, reached in seen if done]
    assert any(mode == Mode.MISSION and reached < last for mode, reached in after_clock)  # the autopilot still flew
    assert all(mode == Mode.MISSION for mode, reached in after_clock if reached < last)  # never "hold" meanwhile
    assert drv.tel.reached_seq == last and not drv.external_modes
    assert sorted(e.capture_id for e in events) == [11, 12, 13]
    for e in events:  # at their points (the clock would have fired them ~half way there)
        w = next(w for w in traj.waypoints if w.capture_id == e.capture_id)
        assert math.dist(e.pos, w.pos) < 2.1  # within the capture radius or ArduCopter's 2 m waypoint radius
