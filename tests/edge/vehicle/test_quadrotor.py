"""The quadrotor plant: translational/rotational dynamics (P10)-(P12), saturation, disturbance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edge.vehicle.quadrotor import (
    Disturbance,
    DisturbanceParams,
    QuadParams,
    Quadrotor,
    body_rates_from_euler_rates,
    euler_rates_from_body_rates,
)

NODRAG = QuadParams(drag_xy=0.0, drag_z=0.0, motor_tau=0.0)


def test_free_fall_matches_closed_form():
    q = Quadrotor(NODRAG, 1 / 200, pos=(0, 0, 100), ground_z=None)
    for _ in range(200):
        q.step(0.0, 0.0, 0.0, 0.0)
    assert q.pos[2] == pytest.approx(100 - 0.5 * 9.81 * 1.0**2, abs=1e-9)
    assert q.vel[2] == pytest.approx(-9.81, abs=1e-9)


def test_hover_thrust_balances_gravity_and_tilt_accelerates_sideways():
    q = Quadrotor(NODRAG, 1 / 200, pos=(0, 0, 10), ground_z=None)
    for _ in range(400):
        q.step(NODRAG.hover_thrust, 0.0, 0.0, 0.0)
    assert q.pos == pytest.approx((0, 0, 10), abs=1e-9)
    # pitched by θ with thrust m g / cos θ: a_x = g tan θ, no vertical acceleration (ψ = 0)
    th = math.radians(10)
    q.s = (0, 0, 10, 0, 0, 0, 0.0, th, 0.0, 0, 0, 0)
    q.step(NODRAG.hover_thrust / math.cos(th), 0, 0, 0)
    assert q.vel[0] == pytest.approx(9.81 * math.tan(th) * q.dt, rel=1e-6)
    assert q.vel[2] == pytest.approx(0.0, abs=1e-9)
    # rolled positive (right wing down) moves towards −y, as the (P7) third column says
    q.s = (0, 0, 10, 0, 0, 0, th, 0.0, 0.0, 0, 0, 0)
    q.step(NODRAG.hover_thrust / math.cos(th), 0, 0, 0)
    assert q.vel[1] < 0


def test_torque_free_rotation_conserves_energy_and_momentum():
    P = NODRAG
    q = Quadrotor(P, 1 / 200, pos=(0, 0, 1000), ground_z=None)
    q.s = (0, 0, 1000, 0, 0, 0, 0.1, 0.2, 0.3, 1.0, 0.5, 2.0)
    I = np.array([P.ixx, P.iyy, P.izz])

    def invariants():
        w = np.array(q.rates)
        return 0.5 * np.sum(I * w * w), np.linalg.norm(I * w)

    e0, h0 = invariants()
    for _ in range(1000):
        q.step(P.hover_thrust, 0.0, 0.0, 0.0)
    e1, h1 = invariants()
    assert e1 == pytest.approx(e0, rel=1e-6)
    assert h1 == pytest.approx(h0, rel=1e-6)
    # the rates did change (gyroscopic coupling f(X) of (P12) is active)
    assert not np.allclose(q.rates, (1.0, 0.5, 2.0))


def test_body_rate_relation_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(20):
        att = tuple(rng.uniform(-1.2, 1.2, 3))
        datt = tuple(rng.normal(size=3))
        w = body_rates_from_euler_rates(att, datt)
        np.testing.assert_allclose(euler_rates_from_body_rates(att, w), datt, atol=1e-12)
    with pytest.raises(ValueError):
        euler_rates_from_body_rates((0.0, math.pi / 2, 0.0), (0.0, 0.0, 1.0))


def test_actuators_saturate():
    P = QuadParams(motor_tau=0.0)
    q = Quadrotor(P, 1 / 200, pos=(0, 0, 10), ground_z=None)
    q.step(1e6, 100.0, -100.0, 100.0)
    assert q.thrust == pytest.approx(P.thrust_max)
    assert q.torque == pytest.approx((2.0, -2.0, 0.5))
    q.step(-5.0, 0, 0, 0)
    assert q.thrust == 0.0
    with pytest.raises(ValueError):
        q.step(math.nan, 0, 0, 0)


def test_motor_lag_is_first_order():
    P = QuadParams(motor_tau=0.02)
    q = Quadrotor(P, 1 / 200, pos=(0, 0, 10), ground_z=None)
    q.step(10.0, 0, 0, 0)
    assert q.thrust == pytest.approx(10.0 * (1 - math.exp(-0.005 / 0.02)))


def test_ground_stops_the_vehicle():
    q = Quadrotor(QuadParams(), 1 / 200, pos=(0, 0, 0.5), ground_z=0.0)
    q.on_ground = False
    for _ in range(200):
        q.step(0.0, 0, 0, 0)
    assert q.pos[2] == 0.0 and q.on_ground and q.vel == (0.0, 0.0, 0.0)
    for _ in range(100):  # on the ground with thrust below weight: stays put
        q.step(5.0, 0.1, 0, 0)
    assert q.pos[2] == 0.0 and q.att == (0.0, 0.0, 0.0)
    for _ in range(100):  # full thrust lifts off
        q.step(1e3, 0, 0, 0)
    assert q.pos[2] > 0.1


def test_disturbance_bounded_and_seeded():
    p = DisturbanceParams(torque_amp=(0.03, 0.02, 0.01), gust_std=(1.0, 1.0, 0.3), gust_bound=2.0,
                          wind_mean=(1.0, 0.0, 0.0))
    a = Disturbance(p, 1 / 200, np.random.default_rng(7), block=500)
    b = Disturbance(p, 1 / 200, np.random.default_rng(7), block=500)
    xa = np.array([a.sample() for _ in range(3000)])
    xb = np.array([b.sample() for _ in range(3000)])
    np.testing.assert_array_equal(xa, xb)
    assert np.all(np.abs(xa[:, :3]) <= np.array([0.03, 0.02, 0.01]) + 1e-15)
    assert np.all(np.abs(xa[:, 3:] - [1.0, 0, 0]) <= 2.0 + 1e-12)
    assert xa[:, 3].mean() == pytest.approx(1.0, abs=0.6)
    assert xa[:, 0].std() > 0.005  # not trivially zero
    c = Disturbance(p, 1 / 200, np.random.default_rng(8), block=500)
    assert not np.array_equal(xa, np.array([c.sample() for _ in range(3000)]))


@pytest.mark.parametrize(
    "kw", [dict(mass=0.0), dict(thrust_to_weight=0.9), dict(ixx=math.nan), dict(torque_max=(1.0, -1.0, 1.0)),
           dict(motor_tau=-0.1)],
)
def test_bad_params_raise(kw):
    with pytest.raises(ValueError):
        QuadParams(**kw)


def test_bad_construction_raises():
    with pytest.raises(ValueError):
        Quadrotor(QuadParams(), dt=0.1)
    with pytest.raises(ValueError):
        Quadrotor(QuadParams(), pos=(0, 0, math.inf))
    with pytest.raises(ValueError):
        DisturbanceParams(gust_std=(-1.0, 0, 0))


def test_ar1_is_scipys_first_order_filter_without_scipy_in_the_edge():
    """the disturbance's OU filter without scipy.signal (75 MB per edge process)."""
    import subprocess
    import sys

    import numpy as np
    from scipy.signal import lfilter

    from edge.vehicle.quadrotor import ar1

    w = np.random.default_rng(3).normal(size=500)
    for a, zi in [(0.97, 0.3), (0.0, 0.0), (0.999, -2.0)]:
        y, zf = ar1(a, w, zi)
        ref, ref_zf = lfilter([1.0], [1.0, -a], w, zi=[zi])
        np.testing.assert_allclose(y, ref, rtol=1e-12, atol=1e-12)
        assert zf == pytest.approx(float(ref_zf[0]), rel=1e-12, abs=1e-12)
    code = ("import sys, edge.board, edge.camera_service, edge.vehicle.factory, edge.vehicle.sim, edge.camera; "
            "print(sorted(m for m in sys.modules if m.startswith('scipy.signal')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr
