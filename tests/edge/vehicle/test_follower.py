"""Trajectory follower: interpolation through the waypoints, yaw, capture points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.vehicle.follower import Follower
from protocol.messages import Trajectory, Waypoint


def _traj(points, times, yaws=None, captures=None):
    yaws = yaws or [0.0] * len(points)
    captures = captures or [None] * len(points)
    return Trajectory(uav=1, waypoints=[
        Waypoint(t=t, pos=p, yaw=y, capture_id=c) for p, t, y, c in zip(points, times, yaws, captures)
    ])


SQUARE = [(0, 0, 10), (10, 0, 10), (10, 10, 10), (0, 10, 10), (0, 0, 10)]


@pytest.mark.parametrize("interp", ["cubic", "linear"])
def test_passes_through_waypoints_at_their_times(interp):
    f = Follower(_traj(SQUARE, [0, 4, 8, 12, 16]), interp)
    for p, t in zip(SQUARE, [0, 4, 8, 12, 16]):
        np.testing.assert_allclose(f.reference(t)[0], p, atol=1e-9)
    # clamped outside the time range, at rest
    assert f.reference(-1.0)[0] == SQUARE[0] and f.reference(99)[0] == SQUARE[-1]
    assert f.reference(99)[1] == (0.0, 0.0, 0.0)


def test_cubic_velocity_is_continuous_and_consistent():
    f = Follower(_traj(SQUARE, [0, 4, 8, 12, 16]))
    ts = np.arange(0.0, 16.0, 0.001)
    P = np.array([f.reference(t)[0] for t in ts])
    V = np.array([f.reference(t)[1] for t in ts])
    A = np.array([f.reference(t)[2] for t in ts])
    # velocity matches the derivative of position, acceleration that of velocity
    np.testing.assert_allclose(np.gradient(P, ts, axis=0)[1:-1], V[1:-1], atol=2e-3)
    # (acceleration is piecewise linear: C1 spline, so compare away from the knots)
    away = np.min(np.abs(ts[:, None] - np.array([0, 4, 8, 12, 16])), axis=1) > 0.005
    np.testing.assert_allclose(np.gradient(V, ts, axis=0)[away], A[away], atol=2e-2)
    assert np.max(np.abs(np.diff(V, axis=0))) < 0.01  # no jumps
    np.testing.assert_allclose(V[0], 0.0, atol=1e-9)  # starts at rest
    # at a corner the tangent is the central difference
    np.testing.assert_allclose(f.reference(4.0)[1], [1.25, 1.25, 0.0], atol=1e-9)


def test_linear_velocity_is_segment_velocity():
    f = Follower(_traj(SQUARE, [0, 4, 8, 12, 16]), "linear")
    assert f.reference(2.0)[1] == pytest.approx((2.5, 0.0, 0.0))
    assert f.reference(5.0)[1] == pytest.approx((0.0, 2.5, 0.0))


def test_yaw_takes_the_short_way():
    f = Follower(_traj([(0, 0, 5), (1, 0, 5)], [0, 1], yaws=[math.radians(170), math.radians(-170)]))
    assert f.reference(0.5)[3] == pytest.approx(math.pi)


def test_segment_and_progress():
    f = Follower(_traj(SQUARE, [10, 14, 18, 22, 26]))
    assert f.segment(9.0) == -1 and f.segment(10.0) == 0 and f.segment(15) == 1 and f.segment(30) == 4
    assert f.progress(10.0) == 0.0 and f.progress(18.0) == 0.5 and f.progress(40) == 1.0


def test_captures_fire_once_in_order():
    f = Follower(_traj(SQUARE, [0, 4, 8, 12, 16], captures=[None, 7, None, 9, 11]))
    assert f.captures_total == 3
    assert f.due_captures(3.9) == []
    assert [w.capture_id for w in f.due_captures(4.0)] == [7]
    assert f.due_captures(4.1) == []
    assert [w.capture_id for w in f.due_captures(100)] == [9, 11]
    assert f.due_captures(200) == [] and f.captures_fired == 3


def test_single_waypoint_is_a_point():
    f = Follower(_traj([(1, 2, 3)], [5.0]))
    assert f.reference(0.0)[0] == (1.0, 2.0, 3.0) and f.reference(10.0)[0] == (1.0, 2.0, 3.0)
    assert f.progress(5.0) == 1.0


def test_bad_input_raises():
    with pytest.raises(ValueError):
        Follower([])
    with pytest.raises(ValueError):
        Follower(_traj(SQUARE[:2], [0, 1]), "spline")
