"""Captures where they belong (services/gcs/capture_pose.py): the frame's position from the UAV's states."""

import pytest

from protocol.messages import DefectReport, Mode, Trajectory, VehicleState, Waypoint
from services.gcs.capture_pose import CAPTURE_TOLERANCE_M, capture_errors, far_captures, far_text

TRAJ = Trajectory(uav=2, waypoints=[Waypoint(t=0, pos=(0, 0, 5)), Waypoint(t=10, pos=(20, 0, 5), capture_id=7),
                                    Waypoint(t=20, pos=(40, 0, 5), capture_id=8)])


def state(stamp: float, x: float) -> VehicleState:
    return VehicleState(uav=2, seq=int(stamp * 10), t=stamp, stamp=100.0 + stamp, pos=(x, 0, 5), vel=(0, 0, 0),
                        att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION)


def report(cid: int, at: float, ok: bool = True) -> DefectReport:
    return DefectReport(uav=2, capture_id=cid, stamp_capture=100.0 + at, stamp_report=101.0 + at, method="it+r",
                        ok=ok)


def test_on_time_frames_pass_and_a_frame_taken_far_from_its_point_is_named():
    # the UAV flies at 2 m/s, states at 10 Hz: at t = 10 it is at x = 20 (capture 7), at t = 12 x = 24
    states = [state(k / 10, 2 * k / 10) for k in range(0, 301)]
    errs = capture_errors([TRAJ], states, [report(7, 10.05), report(8, 12.0)])
    assert errs[(2, 7)] == pytest.approx(0.1, abs=1e-6)  # interpolated between two states
    assert errs[(2, 8)] == pytest.approx(16.0)  # capture 8 fired at x = 24, planned at x = 40
    far = far_captures([TRAJ], states, [report(7, 10.05), report(8, 12.0)])
    assert far == {(2, 8): pytest.approx(16.0)}
    text = far_text(far)
    assert "UAV 2 capture 8 at 16.0 m" in text and f"{CAPTURE_TOLERANCE_M:g} m" in text


def test_unplaceable_unplanned_and_failed_frames_are_not_judged_here():
    states = [state(0.0, 0.0), state(0.1, 0.2)]
    assert capture_errors([TRAJ], states, [report(7, 50.0)]) == {}  # no state within a second
    assert capture_errors([TRAJ], states, [report(99, 0.05)]) == {}  # not a planned capture
    assert capture_errors([TRAJ], states, [report(7, 0.05, ok=False)]) == {}
    assert capture_errors([TRAJ], [], [report(7, 0.05)]) == {}


def test_a_frame_inside_a_gap_in_the_states_is_placed_only_at_a_state_next_to_it():
    # a lost link: no state between t = 8 and t = 12 (the UAV flew on at 2 m/s); the frame of capture 7 at
    # t = 10 is where planned, but the nearest states are 2 s (4 m) away: not placed, so not refused
    states = [state(k / 10, 2 * k / 10) for k in range(0, 81)] + [state(k / 10, 2 * k / 10) for k in range(120, 301)]
    assert capture_errors([TRAJ], states, [report(7, 10.0)]) == {}
    assert capture_errors([TRAJ], states, [report(7, 8.05)])[(2, 7)] == pytest.approx(4.0)  # next to t = 8
