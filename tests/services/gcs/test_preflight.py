"""Pre-flight fit of a plan in the scenario's box (issue 18), on real plans of the planner."""

import pytest

from protocol.messages import Box
from services.gcs.mission import with_formation_size
from services.gcs.preflight import along_track_span, margin_to_box, plan_problem, transit_margin_s
from services.planner.mission import plan_mission
from protocol.scenario import load_scenario


def _plan(n: int):
    sc = with_formation_size(load_scenario(), n)
    return sc, plan_mission(sc, particles=30, iterations=30)


def test_the_papers_three_uavs_fit():
    sc, plan = _plan(3)
    assert plan_problem(plan, sc.formation.offsets) == ""


def test_a_fleet_too_long_for_the_box_is_refused_with_the_reason():
    # 24 UAVs in one line, 3 m apart on two rows (the layout before the fleet stacked in rows): ±18 m
    line = [(0.0, 0.0, 2.0), (3.0, 0.0, -1.0), (-3.0, 0.0, -1.0)]
    for k in range(1, 7):
        line += [(3.0 * k, 0.0, 2.0), (-3.0 * k, 0.0, 2.0), (3.0 * (k + 1), 0.0, -1.0), (-3.0 * (k + 1), 0.0, -1.0)]
    line = line[:24]
    sc = load_scenario()
    sc = sc.model_copy(update={"formation": sc.formation.model_copy(update={"offsets": line})})
    plan = plan_mission(sc, particles=30, iterations=30)
    why = plan_problem(plan, sc.formation.offsets)
    assert "outside the geofence" in why and "of 24 UAVs" in why, why
    assert "18 m behind" in why and "start is 8.0 m" in why, why


def test_a_stacked_fleet_of_24_fits():
    sc, plan = _plan(24)
    assert plan_problem(plan, sc.formation.offsets) == ""


def test_transit_margin_covers_the_farthest_launch_point():
    sc, plan = _plan(3)
    first = {t.uav: t.waypoints[0].pos for t in plan.trajectories}
    at = {u: (p[0], p[1] + 12.0, p[2]) for u, p in first.items()}  # 12 m beside the first waypoint
    assert transit_margin_s(at, plan, speed=1.0, transit_speed=3.0) == pytest.approx(4.0)
    assert transit_margin_s(at, plan, speed=4.0, transit_speed=3.0) == pytest.approx(1.0)  # 4x clock
    assert transit_margin_s({}, plan) == 0.0
    with pytest.raises(ValueError):
        transit_margin_s(at, plan, speed=float("nan"))


def test_span_and_margin():
    assert along_track_span([[0, 0, 2], [3, 0, -1], [-3, 0, -1]]) == (3.0, 3.0)
    assert along_track_span([[1, 0, 0]]) == (0.0, 1.0)
    box = Box(lo=(0, 0, 0), hi=(100, 140, 40))
    assert margin_to_box((40, 8, 30), box) == pytest.approx(8.0)
    assert margin_to_box((-2, 50, 30), box) == pytest.approx(-2.0)
