"""services.gcs.verdict: planned captures and the reached-goal check, shared by the verdict and the report."""

from __future__ import annotations

import pytest

from protocol.messages import DefectReport, Mode, Trajectory, VehicleState, Waypoint
from services.gcs.verdict import (
    GOAL_RADIUS_M,
    goal_check,
    imaged_captures,
    not_imaged_text,
    planned_captures,
    short_of_goal,
)

TRAJ = Trajectory(uav=1, waypoints=[Waypoint(t=0.0, pos=(0, 0, 10)), Waypoint(t=5.0, pos=(10, 0, 10), capture_id=3),
                                    Waypoint(t=10.0, pos=(20, 0, 10), capture_id=4)])


def state(seq: int, t: float, x: float, mode: Mode = Mode.MISSION, progress: float = 0.5) -> VehicleState:
    return VehicleState(uav=1, seq=seq, t=t, stamp=100.0 + t, pos=(x, 0.0, 10.0), vel=(0, 0, 0), att=(0, 0, 0),
                        rates=(0, 0, 0), mode=mode, armed=True, wp_index=1, progress=progress)


def test_planned_and_imaged_captures():
    other = Trajectory(uav=2, waypoints=[Waypoint(t=0.0, pos=(0, 3, 10), capture_id=3)])
    assert planned_captures([TRAJ, other]) == {(1, 3), (1, 4), (2, 3)}
    assert planned_captures([]) == set()
    reports = [DefectReport(uav=1, capture_id=3, stamp_capture=1.0, stamp_report=1.1, method="m", ok=True),
               DefectReport(uav=1, capture_id=4, stamp_capture=1.0, stamp_report=1.1, method="m", ok=False)]
    assert imaged_captures(reports) == {(1, 3)}


def test_the_captures_not_imaged_are_named_with_the_detectors_reason():
    def failed(c: int, why: str) -> DefectReport:
        return DefectReport(uav=2, capture_id=c, stamp_capture=1.0, stamp_report=1.1, method="m", ok=False, error=why)

    reports = [failed(3, "first try"), failed(3, "frame shows no surface: blank"), failed(5, "x" * 500),
               failed(9, "not missing")]
    text = not_imaged_text({(2, 3), (2, 5), (1, 1)}, 26, reports, reason_chars=20)
    assert text == ("3 of 26 capture points were not imaged: uav1-00001, uav2-00003 (frame shows no surfa), "
                    f"uav2-00005 ({'x' * 20})")
    many = not_imaged_text({(1, c) for c in range(15)}, 30, [], most=10)
    assert many.startswith("15 of 30 capture points were not imaged: uav1-00000, ") and many.endswith("uav1-00009, ...")


def test_the_goal_is_checked_where_the_trajectory_ended():
    # completed 1 m short of the goal, then flown off (landing): the end is where progress reached 1
    states = [state(0, 0.0, 0.0), state(1, 10.0, 19.0, progress=1.0), state(2, 12.0, 40.0, Mode.LAND, 1.0)]
    check = goal_check(reversed(states), TRAJ)  # any order: sorted by simulation time
    assert check.completed and check.reached and check.distance_m == pytest.approx(1.0)
    # a HOLD at the end counts; a LAND does not
    assert goal_check([state(0, 1.0, 19.5, Mode.HOLD, 1.0)], TRAJ).completed
    assert not goal_check([state(0, 1.0, 19.5, Mode.LAND, 1.0)], TRAJ).completed


def test_a_trajectory_never_completed_is_measured_from_the_last_position():
    check = goal_check([state(0, 0.0, 0.0), state(1, 5.0, 20.0 - GOAL_RADIUS_M / 2)], TRAJ)
    assert not check.completed and check.reached  # close, but the verdict needs both
    far = goal_check([state(0, 0.0, 0.0), state(1, 5.0, 10.0)], TRAJ)
    assert not far.reached and far.distance_m == pytest.approx(10.0)
    assert goal_check([], TRAJ) is None


def test_a_uav_holding_short_of_its_goal_is_waited_for_and_no_other():
    # a board that fell behind its clock (a loaded machine) holds at its trajectory's end metres short of the goal:
    # the ground station waits for it before landing the fleet (it landed it there, and the verdict failed it)
    goal_x = TRAJ.waypoints[-1].pos[0]
    short = state(9, 20.0, goal_x - GOAL_RADIUS_M - 0.5, Mode.HOLD, 1.0)
    there = state(9, 20.0, goal_x - GOAL_RADIUS_M + 0.5, Mode.HOLD, 1.0)
    assert short_of_goal({1: short}, [TRAJ]) == [1]
    assert short_of_goal({1: there}, [TRAJ]) == []
    for other in (state(9, 20.0, 0.0, Mode.MISSION, 0.9), state(9, 20.0, 0.0, Mode.LAND, 1.0),
                  state(9, 20.0, 0.0, Mode.RTL, 1.0)):
        assert short_of_goal({1: other}, [TRAJ]) == []  # still flying it, or not going there any more
    assert short_of_goal({}, [TRAJ]) == []  # never heard
