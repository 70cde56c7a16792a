"""MissionSequencer and Mover on their own: no physics, the 'vehicle' is wherever the test says."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.vehicle.follower import Follower
from edge.vehicle.sequencer import MIN_CLEARANCE, MissionSequencer, Mover
from protocol.messages import Trajectory, Waypoint

DT = 0.01


def line(uav=1, start=(0.0, 0.0, 10.0), n=5, spacing=4.0, speed=2.0, t0=0.0, yaw=0.0) -> Trajectory:
    """n waypoints along +x, one every spacing/speed s from t0, capture ids 100.."""
    return Trajectory(uav=uav, waypoints=[
        Waypoint(t=t0 + i * spacing / speed, pos=(start[0] + i * spacing, start[1], start[2]), yaw=yaw + 0.1 * i,
                 capture_id=100 + i) for i in range(n)])


def seq(**kw) -> MissionSequencer:
    return MissionSequencer(1, 0.0, **kw)


def fly(m: MissionSequencer, t: float, until: float, pos=None, lag: float = 1.0):
    """Call reference/due every DT from t to until with a vehicle that moves ``lag`` of the way to the
    reference each step (1.0: exactly on it; pos fixed: it never moves). Returns (t, refs, captures)."""
    refs, caps = [], []
    here = pos
    while t < until - 1e-12 and not m.done:
        p = here if here is not None else (0.0, 0.0, 0.0)
        r = m.reference(t, p, DT)
        refs.append((t, m.phase, r))
        caps += [(w.capture_id, t) for w in m.due(t)]
        if pos is None:
            q = r[0] if here is None else here
            here = tuple(q[i] + lag * (r[0][i] - q[i]) for i in range(3))
        t = round(t + DT, 9)
    return t, refs, caps


# ------------------------------------------------------------------ Mover
def test_mover_constant_speed_then_rests_at_target():
    m = Mover((1.0, 2.0, 3.0), (1.0, 2.0 + 6.0, 3.0 + 8.0), 5.0, 10.0)  # 10 m at 5 m/s: 2 s
    assert m.at(9.0) == ((1.0, 2.0, 3.0), (0.0, 0.0, 0.0), False)  # before t0: at the start, not moving
    p, v, done = m.at(11.0)
    assert p == pytest.approx((1.0, 5.0, 7.0)) and v == pytest.approx((0.0, 3.0, 4.0)) and not done
    p, v, done = m.at(12.5)
    assert p == pytest.approx((1.0, 8.0, 11.0)) and v == (0.0, 0.0, 0.0) and done


def test_mover_zero_length_is_done_at_once_and_bad_input_raises():
    assert Mover((1.0, 1.0, 1.0), (1.0, 1.0, 1.0), 2.0, 0.0).at(0.0) == ((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), True)
    for speed in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="speed"):
            Mover((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), speed, 0.0)
    with pytest.raises(ValueError, match="finite"):
        Mover((0.0, 0.0, 0.0), (math.nan, 0.0, 0.0), 1.0, 0.0)


# ------------------------------------------------------------------ construction, upload
@pytest.mark.parametrize("kw", [dict(uav=0), dict(uav=256), dict(ground_z=math.nan), dict(transit_speed=0.0),
                                dict(start_radius=-1.0), dict(arrive_radius=math.inf), dict(offset_rate=math.nan),
                                dict(max_offset=-0.1), dict(interpolation="spline")])
def test_bad_construction_raises(kw):
    args = dict(uav=1, ground_z=0.0) | kw
    uav, gz = args.pop("uav"), args.pop("ground_z")
    with pytest.raises(ValueError):
        MissionSequencer(uav, gz, **args)


def test_upload_checks_type_uav_and_ground_clearance():
    m = MissionSequencer(2, ground_z=3.0)
    with pytest.raises(ValueError, match="Trajectory"):
        m.load({"uav": 2})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="for UAV 1, this is UAV 2"):
        m.load(line(uav=1, start=(0, 0, 10)))
    with pytest.raises(ValueError, match="waypoint 0 is below"):  # 10 m is fine over z = 0, not 0.2 m over z = 9.8
        MissionSequencer(2, ground_z=10.0 - MIN_CLEARANCE + 0.3).load(line(uav=2))
    f = m.load(line(uav=2))
    assert isinstance(f, Follower) and m.follower is f and m.captures == 0 and not m.done


def test_driver_extra_check_runs_after_the_shared_ones_and_before_any_change():
    m = seq()
    first = m.load(line())
    calls = []

    def too_fast(traj):
        calls.append(traj)
        raise ValueError("too fast for this vehicle")

    with pytest.raises(ValueError, match="UAV 2"):  # shared check first: the extra one never sees it
        m.load(line(uav=2), check=too_fast)
    assert calls == []
    with pytest.raises(ValueError, match="too fast"):
        m.load(line(n=3), check=too_fast)
    assert len(calls) == 1 and m.follower is first  # refused: the old trajectory stays


def test_start_and_resume_refusals():
    m = seq()
    with pytest.raises(ValueError, match="no trajectory uploaded"):
        m.start(0.0, (0.0, 0.0, 10.0))
    m.load(line())
    with pytest.raises(ValueError, match="t0 must be finite"):
        m.start(0.0, (0.0, 0.0, 10.0), t0=math.nan)
    assert m.phase == ""
    with pytest.raises(ValueError, match="no paused mission"):
        m.resume(0.0, (0.0, 0.0, 10.0), 0.0)
    with pytest.raises(ValueError, match="no mission in flight"):
        m.reference(0.0, (0.0, 0.0, 10.0), DT)
    assert m.progress(0.0) == (-1, 0.0) and seq().progress(5.0) == (-1, 0.0)


# ------------------------------------------------------------------ start, track, end
def test_started_at_the_first_waypoint_tracks_the_follower_and_fires_each_capture_once():
    traj = line(t0=5.0)  # trajectory time starts at 5 s
    m = seq()
    m.load(traj)
    ref = Follower(traj)
    m.start(100.0, (0.0, 0.0, 10.0))
    assert m.phase == "track"
    for t in (100.0, 101.3, 104.9):
        p, v, a, yaw = m.reference(t, (0.0, 0.0, 10.0), DT)
        assert (p, v, a, yaw) == ref.reference(t - 100.0 + 5.0)
    assert m.progress(104.0) == (2, pytest.approx(0.5))
    t, refs, caps = fly(m, 100.0, 120.0)
    assert [c for c, _ in caps] == [100, 101, 102, 103, 104]
    assert [round(tc - 100.0, 6) for _, tc in caps] == [0.0, 2.0, 4.0, 6.0, 8.0]  # at their times
    assert m.done and m.phase == "" and m.captures == 5
    assert refs[-1][2] == ((16.0, 0.0, 10.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), pytest.approx(0.4))
    assert m.progress(500.0) == (4, 1.0)  # done: stays at the end
    assert m.due(500.0) == []


def test_start_in_the_past_at_the_first_waypoint_catches_up_and_fires_passed_captures_at_once():
    m = seq()
    m.load(line())
    m.start(10.0, (0.0, 0.0, 10.0), t0=7.0)  # trajectory time is already 3 s
    m.reference(10.0, (0.0, 0.0, 10.0), DT)
    assert [w.capture_id for w in m.due(10.0)] == [100, 101]
    assert m.progress(10.0) == (1, pytest.approx(3.0 / 8.0))


def test_future_start_waits_at_the_first_waypoint_with_its_yaw():
    m = seq()
    m.load(line(yaw=0.7))
    m.start(0.0, (0.2, 0.0, 10.0), t0=3.0)
    assert m.phase == "wait"
    assert m.reference(2.99, (0.0, 0.0, 10.0), DT) == ((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.7)
    assert m.due(2.99) == [] and m.progress(2.99) == (-1, 0.0)
    m.reference(3.0, (0.0, 0.0, 10.0), DT)
    assert m.phase == "track" and [w.capture_id for w in m.due(3.0)] == [100]


def test_far_start_transits_from_the_given_reference_and_the_clock_starts_on_arrival():
    m = seq(transit_speed=2.0, arrive_radius=0.3)
    m.load(line())
    m.start(0.0, (0.0, 10.0, 10.0), t0=1.0, ref=(0.0, 10.5, 10.0))  # 10 m away; reference 0.5 m further
    assert m.phase == "transit"
    p, v, a, _ = m.reference(0.0, (0.0, 10.0, 10.0), DT)
    assert p == (0.0, 10.5, 10.0) and v == pytest.approx((0.0, -2.0, 0.0))  # leaves from ref, not from pos
    # the reference has arrived (5.25 s) but the vehicle lags 1 m behind: still in transit
    m.reference(6.0, (0.0, 1.0, 10.0), DT)
    assert m.phase == "transit"
    m.reference(6.5, (0.0, 0.1, 10.0), DT)  # now within arrive_radius, after t0 = 1: tracks from the arrival
    assert m.phase == "track" and m.tau(6.5) == 0.0 and m.tau(7.5) == 1.0


def test_transit_arriving_before_the_start_time_waits_for_it():
    m = seq(transit_speed=10.0)
    m.load(line())
    m.start(0.0, (0.0, 5.0, 10.0), t0=4.0)
    t, refs, _ = fly(m, 0.0, 3.0)
    assert refs[-1][1] == "wait"
    fly(m, t, 4.5)
    assert m.phase == "track" and m.tau(4.5) == pytest.approx(0.5)


# ------------------------------------------------------------------ pause, resume, cancel
def test_pause_freezes_progress_and_resume_continues_from_the_paused_time():
    m = seq()
    m.load(line())
    m.start(0.0, (0.0, 0.0, 10.0))
    t, _, caps = fly(m, 0.0, 3.0)
    assert [c for c, _ in caps] == [100, 101]
    m.pause(t)
    assert m.phase == "" and m.paused
    frozen = m.progress(t)
    assert m.progress(t + 50.0) == frozen == (1, pytest.approx(3.0 / 8.0))
    here = m.follower.reference(3.0)[0]
    m.resume(t + 50.0, here, 0.0)  # within start_radius of the paused point: tracks at once
    assert m.phase == "track" and not m.paused and m.tau(t + 50.0) == pytest.approx(3.0)
    _, _, caps = fly(m, t + 50.0, t + 60.0)
    assert [c for c, _ in caps] == [102, 103, 104] and m.captures == 5


def test_resume_far_away_flies_back_to_the_paused_point_and_a_second_pause_keeps_it():
    m = seq(transit_speed=4.0)
    m.load(line())
    m.start(0.0, (0.0, 0.0, 10.0))
    m.reference(3.0, (0.0, 0.0, 10.0), DT)
    assert [w.capture_id for w in m.due(3.0)] == [100, 101]
    m.pause(3.0)
    paused_at = m.follower.reference(3.0)[0]
    m.resume(10.0, (paused_at[0], paused_at[1] + 8.0, 10.0), yaw=1.2)  # pushed 8 m sideways
    assert m.phase == "transit_resume"
    p, v, _, yaw = m.reference(10.5, (paused_at[0], paused_at[1] + 6.0, 10.0), DT)
    assert p == pytest.approx((paused_at[0], paused_at[1] + 6.0, 10.0)) and yaw == 1.2  # heading kept
    m.pause(10.5)  # paused again on the way back
    assert m.progress(10.5) == (1, pytest.approx(3.0 / 8.0))
    m.resume(20.0, (paused_at[0], paused_at[1] + 6.0, 10.0), yaw=1.2)
    assert m.phase == "transit_resume"  # still heading back to the paused point, not the start
    t, refs, caps = fly(m, 20.0, 40.0)
    track = [r for r in refs if r[1] == "track"]
    assert track[0][2][0] == pytest.approx(paused_at, abs=0.05)  # on track exactly where it stopped
    assert [c for c, _ in caps] == [102, 103, 104]


def test_paused_before_the_first_waypoint_resumes_to_it_and_keeps_the_start_time():
    m = seq(transit_speed=5.0)
    m.load(line())
    m.start(0.0, (0.0, 10.0, 10.0), t0=30.0)
    fly(m, 0.0, 1.0)
    m.pause(1.0)
    assert m.paused and m.progress(1.0) == (-1, 0.0)
    m.resume(5.0, (0.0, 4.0, 10.0), 0.0)
    assert m.phase == "transit"
    t, refs, _ = fly(m, 5.0, 29.0)
    assert refs[-1][1] == "wait"  # there long before t0: waits for the requested start
    fly(m, t, 30.5)
    assert m.phase == "track" and m.tau(30.5) == pytest.approx(0.5)


def test_cancel_drops_the_paused_mission_and_upload_clears_it():
    m = seq()
    m.load(line())
    m.start(0.0, (0.0, 0.0, 10.0))
    m.reference(0.0, (0.0, 0.0, 10.0), DT)
    m.pause(2.0)
    m.cancel()
    assert not m.paused and m.progress(3.0) == (-1, 0.0)
    with pytest.raises(ValueError, match="no paused mission"):
        m.resume(3.0, (0.0, 0.0, 10.0), 0.0)
    m.start(3.0, (0.0, 0.0, 10.0))
    m.pause(4.0)
    m.load(line())
    assert not m.paused and m.phase == "" and m.captures == 0
    m.pause(5.0)  # nothing in flight: no-op
    assert not m.paused


def test_a_finished_mission_cannot_be_resumed_but_can_be_started_again():
    m = seq()
    m.load(line(n=2))
    m.start(0.0, (0.0, 0.0, 10.0))
    fly(m, 0.0, 5.0)
    assert m.done and not m.paused
    with pytest.raises(ValueError, match="no paused mission"):
        m.resume(6.0, (4.0, 0.0, 10.0), 0.0)
    m.start(6.0, (0.0, 0.0, 10.0))
    assert not m.done and m.phase == "track" and m.captures == 2  # captures fire once per upload
    _, _, caps = fly(m, 6.0, 12.0)
    assert caps == []


def test_a_capture_at_the_very_end_is_handed_out_once_after_the_end_is_reached():
    m = seq()
    m.load(line(n=2))  # captures at 0 and 2 s
    m.start(0.0, (0.0, 0.0, 10.0))
    m.reference(0.0, (0.0, 0.0, 10.0), DT)
    assert [w.capture_id for w in m.due(0.0)] == [100]
    r = m.reference(2.5, (4.0, 0.0, 10.0), DT)  # first call past the end: the last capture is left
    assert m.done and r[0] == (4.0, 0.0, 10.0)
    assert [w.capture_id for w in m.due(2.5)] == [101] and m.due(2.5) == [] and m.captures == 2


# ------------------------------------------------------------------ formation offset
def test_offset_is_bounded_rate_limited_and_only_applied_while_tracking():
    m = seq(max_offset=3.0, offset_rate=1.0)
    assert m.set_offset((0.0, 6.0, 8.0)) == pytest.approx((0.0, 1.8, 2.4))  # norm 10 -> 3, same direction
    m.load(line(n=2, spacing=40.0, speed=2.0))  # 20 s long
    m.start(0.0, (0.0, 0.0, 10.0))
    f = Follower(line(n=2, spacing=40.0, speed=2.0))
    for k, t in enumerate((0.0, 0.5, 1.0)):
        p = m.reference(t, (0.0, 0.0, 10.0), 0.5)[0]
        d = [p[i] - f.reference(t)[0][i] for i in range(3)]
        assert math.hypot(*d) == pytest.approx(0.5 * (k + 1))  # 1 m/s x 0.5 s per call
    t, _, _ = fly(m, 1.5, 6.0)
    assert m.offset == m.offset_cmd == pytest.approx((0.0, 1.8, 2.4))
    p = m.reference(t, (0.0, 0.0, 10.0), DT)[0]
    assert p == pytest.approx(tuple(a + b for a, b in zip(f.reference(t)[0], (0.0, 1.8, 2.4))))
    m.pause(t)
    m.set_offset((0.0, 0.0, 0.0))
    on_traj = f.reference(t)[0]
    m.resume(t + 100.0, on_traj, 0.0)  # paused 100 s: the offset did not move meanwhile, it moves from now
    p2 = m.reference(t + 100.0, on_traj, 0.5)[0]
    assert math.dist(p2, f.reference(t)[0]) == pytest.approx(3.0 - 0.5)
    for bad in ((math.nan, 0.0, 0.0), (1.0, 2.0), "abc"):
        with pytest.raises(ValueError, match="offset"):
            m.set_offset(bad)  # type: ignore[arg-type]


@settings(max_examples=60, deadline=None)
@given(cmds=st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.floats(-20, 20)), min_size=1, max_size=6),
       dt=st.floats(0.001, 0.5))
def test_offset_never_exceeds_the_bound_nor_the_rate(cmds, dt):
    m = seq(max_offset=3.0, offset_rate=1.0)
    m.load(line(n=2, spacing=400.0, speed=2.0))
    m.start(0.0, (0.0, 0.0, 10.0))
    t = 0.0
    for c in cmds:
        m.set_offset(c)
        for _ in range(5):
            before = m.offset
            m.reference(t, (0.0, 0.0, 10.0), dt)
            t += dt
            assert math.hypot(*m.offset) <= 3.0 + 1e-9
            assert math.dist(before, m.offset) <= 1.0 * dt + 1e-9
