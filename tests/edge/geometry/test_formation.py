"""Tests of edge.geometry.formation: (P6)-(P9) geometry and on-board formation keeping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edge.geometry.formation import (
    DEFAULT_OFFSETS,
    centroid_of,
    errors_in_formation,
    errors_to_inertial,
    formation_error,
    headings,
    neighbour_correction,
    rotation_of,
    uav_positions,
)

angles = st.floats(-math.pi, math.pi, allow_nan=False)
OFFSETS = {i + 1: DEFAULT_OFFSETS[i] for i in range(3)}


@given(angles, st.floats(-1.5, 1.5), angles)
@settings(max_examples=50, deadline=None)
def test_rotation_is_orthonormal_with_det_one(phi, theta, psi):
    R = rotation_of(phi, theta, psi)
    assert R.shape == (3, 3)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


def test_rotation_matches_zyx_composition():
    phi, theta, psi = 0.3, -0.4, 1.1
    c, s = math.cos, math.sin
    Rx = np.array([[1, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    Ry = np.array([[c(theta), 0, s(theta)], [0, 1, 0], [-s(theta), 0, c(theta)]])
    Rz = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1]])
    np.testing.assert_allclose(rotation_of(phi, theta, psi), Rz @ Ry @ Rx, atol=1e-14)


def test_rotation_vectorised_over_yaw():
    yaws = np.linspace(-3, 3, 7)
    R = rotation_of(0.0, 0.0, yaws)
    assert R.shape == (7, 3, 3)
    for k, y in enumerate(yaws):
        np.testing.assert_allclose(R[k], rotation_of(0.0, 0.0, y))


def test_errors_transform_back_and_forth():
    rng = np.random.default_rng(1)
    d, a = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    R = rotation_of(rng.normal(size=5), rng.normal(size=5), rng.normal(size=5))
    eF = errors_in_formation(d, a, R)
    np.testing.assert_allclose(errors_to_inertial(eF, R), d - a, atol=1e-12)
    # the norm is frame-independent
    np.testing.assert_allclose(np.linalg.norm(eF, axis=1), np.linalg.norm(d - a, axis=1))


def test_error_along_travel_is_formation_x():
    # heading north: a desired point 1 m further north is +x in the formation frame
    eF = errors_in_formation([0, 1, 0], [0, 0, 0], rotation_of(0, 0, math.pi / 2))
    np.testing.assert_allclose(eF, [1, 0, 0], atol=1e-12)


def test_default_offsets_make_triangle_in_vertical_plane_of_path():
    path = np.array([[0, 0, 30], [10, 10, 30], [20, 20, 30.0]])
    psi = headings(path)
    np.testing.assert_allclose(psi, math.pi / 4)
    P = uav_positions(path, psi)
    assert P.shape == (3, 3, 3)
    for i in range(3):
        np.testing.assert_allclose(centroid_of(P[i]), path[i], atol=1e-12)  # (P6)
        # UAV 1 2 m above, 2 and 3 ahead/behind 3 m along the path, 1 m below
        np.testing.assert_allclose(P[i, 0], path[i] + [0, 0, 2], atol=1e-12)
        np.testing.assert_allclose(P[i, 1], path[i] + [3 / math.sqrt(2), 3 / math.sqrt(2), -1])
        np.testing.assert_allclose(P[i, 2], path[i] + [-3 / math.sqrt(2), -3 / math.sqrt(2), -1])
        # all in the vertical plane containing the path: no cross-track component
        d = np.array([1, 1, 0]) / math.sqrt(2)
        left = np.array([-1, 1, 0]) / math.sqrt(2)
        np.testing.assert_allclose((P[i] - path[i]) @ left, 0, atol=1e-12)
        assert (P[i, 1] - path[i]) @ d == pytest.approx(3.0)
    # side lengths of the triangle
    sides = sorted(np.linalg.norm(P[0, a] - P[0, b]) for a, b in ((0, 1), (1, 2), (0, 2)))
    np.testing.assert_allclose(sides, [math.hypot(3, 3), math.hypot(3, 3), 6.0])


def test_headings_smooth_at_corner_and_carry_over_vertical():
    path = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [10, 10, 5], [10, 20, 5.0]])
    psi = headings(path)
    assert psi[0] == pytest.approx(0.0)
    assert psi[1] == pytest.approx(math.pi / 4)  # mean of east and north at the corner
    assert psi[2] == pytest.approx(math.pi / 2)
    assert psi[3] == pytest.approx(math.pi / 2)
    assert psi[4] == pytest.approx(math.pi / 2)
    assert headings(np.array([[0, 0, 0], [0, 0, 5.0]])).tolist() == [0.0, 0.0]
    assert headings(np.zeros((1, 3))).tolist() == [0.0]


@pytest.mark.parametrize(
    "bad",
    [np.zeros((0, 3)), np.zeros((4, 2)), np.array([[0, 0, np.nan], [1, 1, 1]])],
)
def test_bad_paths_raise(bad):
    with pytest.raises(ValueError):
        headings(bad)
    with pytest.raises(ValueError):
        uav_positions(bad, 0.0)


def test_bad_inputs_raise():
    with pytest.raises(ValueError):
        rotation_of(np.nan, 0, 0)
    with pytest.raises(ValueError):
        centroid_of(np.zeros((0, 3)))
    with pytest.raises(ValueError):
        uav_positions(np.zeros((3, 3)), np.zeros(2))
    with pytest.raises(ValueError):
        neighbour_correction(0.0, [0, 0, 0], {2: ([0, 0, 0], [0, 0, 0], 0.0, np.nan)})
    with pytest.raises(ValueError):
        neighbour_correction(0.0, [0, 0, np.inf], {})


def _slots(c, yaw):
    return uav_positions(np.asarray(c, float), yaw)[0]


def test_formation_error_metric():
    c = np.array([10.0, 5.0, 30.0])
    slots = _slots(c, 0.7)
    pos = {i + 1: slots[i] for i in range(3)}
    assert formation_error(pos, c, 0.7, OFFSETS) == pytest.approx(0.0, abs=1e-12)
    # translating the whole formation does not change the shape error
    moved = {k: v + [4.0, -3.0, 1.0] for k, v in pos.items()}
    assert formation_error(moved, c, 0.7, OFFSETS) == pytest.approx(0.0, abs=1e-12)
    # one UAV 3 m off: deviations from the common centroid are (2, -1, -1) m -> rms sqrt(2)
    bad = dict(pos)
    bad[3] = pos[3] + [3.0, 0, 0]
    assert formation_error(bad, c, 0.7, OFFSETS) == pytest.approx(math.sqrt(2.0))
    # single UAV: absolute slot error
    assert formation_error({2: slots[1] + [0, 0, 1.5]}, c, 0.7, OFFSETS) == pytest.approx(1.5)
    with pytest.raises(ValueError):
        formation_error({7: slots[0]}, c, 0.7, OFFSETS)


# ----------------------------------------------------------------------------- closed loop
def _fly_formation(keep: bool) -> float:
    """Three simulated UAVs fly the (P9) slots of a straight centroid path; UAV 3 is held for 3 s
    (it ends 6 m behind its slot). Returns the RMS shape error over the last 10 s."""
    from edge.vehicle.sim import SimDriver
    from protocol.messages import Mode, Trajectory, Waypoint

    T, v = 30.0, 2.0
    times = np.arange(0.0, T + 1e-9, 2.0)
    centroid = np.stack([v * times, np.zeros_like(times), np.full_like(times, 20.0)], axis=1)
    yaw = headings(centroid)
    slots = uav_positions(centroid, yaw)  # (N, 3, 3)
    drivers = {}
    for n in (1, 2, 3):
        start = slots[0, n - 1]
        d = SimDriver(n, seed=n, home=(start[0], start[1], 0.0))
        d.upload(Trajectory(uav=n, waypoints=[
            Waypoint(t=float(t), pos=tuple(map(float, slots[i, n - 1])), yaw=float(yaw[i])) for i, t in enumerate(times)
        ]))
        d.takeoff(float(start[2]))
        drivers[n] = d
    for d in drivers.values():
        while d.mode != Mode.HOLD:
            d.step(d.t + 0.1)
    t0 = max(d.t for d in drivers.values()) + 1.0
    for d in drivers.values():
        d.start(t0)
    errs, t, dt = [], t0, 0.1
    while t < t0 + T - 0.5:
        t += dt
        if abs(t - (t0 + 5.0)) < dt / 2:
            drivers[3].hold()
        if abs(t - (t0 + 8.0)) < dt / 2:
            drivers[3].resume()
        for d in drivers.values():
            d.step(t)
        pos = {n: np.array(d.state().pos) for n, d in drivers.items()}
        tau = t - t0
        c_plan = np.array([v * tau, 0.0, 20.0])
        if keep:  # as the board does: share (position, plan, trajectory time), correct from the others'
            shared = {}
            for n, d in drivers.items():
                st = d.state()
                tau_n = st.progress * T
                shared[n] = (pos[n], np.array([v * tau_n, 0.0, 20.0]) + OFFSETS[n], tau_n, d.mode == Mode.MISSION)
            for n, d in drivers.items():
                if not shared[n][3]:
                    continue
                neigh = {j: (p, ref, tau_j, 0.1) for j, (p, ref, tau_j, _) in shared.items() if j != n}
                d.set_reference_offset(tuple(neighbour_correction(shared[n][2], (v, 0.0, 0.0), neigh)))
        if tau > T - 10.5:
            errs.append(formation_error(pos, c_plan, 0.0, OFFSETS))
    return float(np.sqrt(np.mean(np.square(errs))))


@pytest.mark.slow
def test_formation_keeping_reduces_shape_error_when_one_uav_lags():
    free = _fly_formation(keep=False)
    kept = _fly_formation(keep=True)
    assert free > 2.0  # UAV 3 really lags (6 m behind its slot)
    # steady state for three UAVs: (2 - 2g) / (2 + g) of the relative lag is left, 0.14 at g = 0.8
    assert kept < 0.3 * free


def test_offsets_for_any_fleet_size_keep_three_metres_apart():
    from edge.geometry.formation import offsets_for

    np.testing.assert_array_equal(offsets_for(3), DEFAULT_OFFSETS)
    np.testing.assert_array_equal(offsets_for(2), DEFAULT_OFFSETS[:2])
    for n in (1, 4, 7, 10):
        o = offsets_for(n)
        assert o.shape == (n, 3)
        d = np.linalg.norm(o[:, None] - o[None], axis=-1) + np.eye(n) * 99
        assert d.min() >= 3.0 - 1e-9
    with pytest.raises(ValueError):
        offsets_for(0)


def test_large_fleets_stack_rows_below_instead_of_lengthening_the_line():
    from edge.geometry.formation import MAX_ALONG_M, ROW_PITCH_M, home_offsets, offsets_for

    for n in (11, 24, 48, 100):
        o = offsets_for(n)
        assert o.shape == (n, 3) and len({tuple(r) for r in o}) == n
        assert np.abs(o[:, 0]).max() <= MAX_ALONG_M  # 12 m long whatever N (24 in a line was ±18 m)
        assert np.all(o[:, 1] == 0.0)  # every UAV in the vertical plane of the path (one stand-off)
        d = np.linalg.norm(o[:, None] - o[None], axis=-1) + np.eye(n) * 99
        assert d.min() >= ROW_PITCH_M - 1e-9
        top2 = o[o[:, 2] >= -1.0]
        assert len(top2) == 10  # the two imaging rows are full before any row goes below
        homes = home_offsets(o)  # stacked UAVs launch side by side, 3 m apart on the ground
        g = np.linalg.norm(homes[:, None] - homes[None], axis=-1) + np.eye(n) * 99
        assert g.min() >= 3.0 - 1e-9
    np.testing.assert_array_equal(offsets_for(48)[:24], offsets_for(24))  # a larger fleet only adds slots
    np.testing.assert_array_equal(home_offsets(offsets_for(3)), DEFAULT_OFFSETS[:, :2])  # the paper's: under the slots


def test_neighbour_correction_from_shared_errors():
    v = np.array([2.0, 0.0, 0.0])
    on_plan = {2: ((3, 0, 19), (3, 0, 19), 9.9, 0.1), 3: ((-3, 0, 19), (-3, 0, 19), 9.9, 0.1)}
    # the states are 0.1 s old, so a neighbour on plan shows a tau 0.1 s behind the own
    np.testing.assert_allclose(neighbour_correction(10.0, v, on_plan), 0.0, atol=1e-12)
    # UAV 3 is 1.5 s behind in its mission (held): its plan and position are 3 m back
    behind = {**on_plan, 3: ((-6, 0, 19), (-6, 0, 19), 8.4, 0.1)}
    np.testing.assert_allclose(neighbour_correction(10.0, v, behind, gain=1.0), [-1.5, 0, 0], atol=1e-12)
    # UAV 2 has a tracking error of 1 m to the left (P8): followed by the same share
    drift = {**on_plan, 2: ((3, 1, 19), (3, 0, 19), 9.9, 0.1)}
    np.testing.assert_allclose(neighbour_correction(10.0, v, drift, gain=0.8), [0, 0.4, 0], atol=1e-12)
    # stale neighbours are ignored; the correction is bounded
    stale = {3: ((-30, 0, 19), (-3, 0, 19), 10.0, 5.0)}
    np.testing.assert_allclose(neighbour_correction(10.0, v, stale), 0.0)
    far = {3: ((-30, 0, 19), (-3, 0, 19), 9.9, 0.1)}
    assert np.linalg.norm(neighbour_correction(10.0, v, far, max_correction=3.0)) == pytest.approx(3.0)
    with pytest.raises(ValueError):
        neighbour_correction(float("nan"), v, on_plan)
    with pytest.raises(ValueError):
        neighbour_correction(10.0, v, on_plan, gain=1.5)
    with pytest.raises(ValueError):
        neighbour_correction(10.0, v, {2: ((float("nan"), 0, 0), (0, 0, 0), 1.0, 0.1)})
    with pytest.raises(ValueError):
        neighbour_correction(10.0, v, on_plan, clock_rate=0.0)


def test_a_late_state_is_not_read_as_a_lagging_neighbour():
    """A state that took 50 ms over SkyNet at a 6x clock is 0.3 s of trajectory old: on plan
    neighbours give no correction however late their states arrive (else the fleet drifts back)."""
    v = np.array([2.0, 0.0, 0.0])
    for age in (0.0, 0.05, 0.2, 0.9):
        late = {2: ((3, 0, 19), (3, 0, 19), 10.0 - 6 * age, age), 3: ((-3, 0, 19), (-3, 0, 19), 10.0 - 6 * age, age)}
        np.testing.assert_allclose(neighbour_correction(10.0, v, late, clock_rate=6.0), 0.0, atol=1e-12)
    # read at the wrong rate the same states look 0.25 s x 2 m/s behind
    late = {2: ((3, 0, 19), (3, 0, 19), 9.7, 0.05)}
    np.testing.assert_allclose(neighbour_correction(10.0, v, late, gain=1.0, clock_rate=1.0), [-0.5, 0, 0])
