"""Pre-flight fit of a plan in the scenario's box, on real plans of the planner."""

import pytest

from protocol.messages import Box
from protocol.scenario import load_scenario
from services.gcs.mission import with_formation_size
from services.gcs.preflight import along_track_span, margin_to_box, plan_problem, transit_margin_s
from services.planner.mission import plan_mission


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


# ----------------------------------------------------------------------------- the plan against the scenario
from protocol.messages import CapturePoint, Trajectory, Waypoint  # noqa: E402
from services.gcs.preflight import scenario_box, scenario_problem  # noqa: E402


def rogue(plan, dx: float = 420.0, top: float = 120.0):
    """The attack's plan: a 6 km geofence, every trajectory shifted ``dx`` m east and climbing to ``top`` m."""
    trajs = []
    for t in plan.trajectories:
        n = len(t.waypoints)
        wps = [w.model_copy(update={"pos": (w.pos[0] + dx * i / max(1, n - 1), w.pos[1],
                                            w.pos[2] + (top - w.pos[2]) * i / max(1, n - 1))})
               for i, w in enumerate(t.waypoints)]
        trajs.append(Trajectory(uav=t.uav, waypoints=wps))
    return plan.model_copy(update={"trajectories": trajs, "geofence": Box(lo=(-3000, -3000, 0), hi=(3000, 3000, 150))})


def test_a_plan_inside_the_scenario_passes_and_the_fence_is_the_scenarios():
    sc, plan = _plan(3)
    assert plan.collision_free and scenario_problem(plan, sc, (1, 2, 3)) == ""
    assert scenario_box(sc) == Box(lo=sc.box.lo, hi=sc.box.hi)


def test_the_rogue_planners_plan_is_refused_whatever_its_own_geofence_says():
    sc, plan = _plan(3)
    bad = rogue(plan)
    why = scenario_problem(bad, sc, (1, 2, 3))  # the first waypoint outside is named, with its UAV
    assert why.startswith("UAV 1 waypoint ") and "outside the scenario's box" in why, why
    # trajectories inside, but a fence of its own wider than the scenario's box: refused too
    why = scenario_problem(plan.model_copy(update={"geofence": bad.geofence}), sc, (1, 2, 3))
    assert "geofence" in why and "reaches outside the scenario's box" in why, why
    # and the old check, which trusted the plan's fence, let it through: the reason for this one
    assert plan_problem(bad, sc.formation.offsets) == ""
    assert "outside the geofence" in plan_problem(bad, sc.formation.offsets, scenario_box(sc))


def test_obstacles_segments_origin_uavs_and_captures_are_checked():
    sc, plan = _plan(3)
    t0 = plan.trajectories[0]
    c = sc.obstacles[0]  # a cylinder of the monorail bridge
    inside = (c.centre[0], c.centre[1], c.height / 2)
    wps = [w.model_copy() for w in t0.waypoints]
    wps[3] = wps[3].model_copy(update={"pos": inside})
    hit = plan.model_copy(update={"trajectories": [Trajectory(uav=1, waypoints=wps), *plan.trajectories[1:]]})
    assert scenario_problem(hit, sc) == f"UAV 1 waypoint 3 at ({inside[0]:.1f}, {inside[1]:.1f}, {inside[2]:.1f}) is inside obstacle 0"
    # two waypoints on either side of the cylinder: the segment between them goes through it
    a = (c.centre[0] - c.radius - 1, c.centre[1], 5.0)
    b = (c.centre[0] + c.radius + 1, c.centre[1], 5.0)
    through = Trajectory(uav=1, waypoints=[Waypoint(t=0, pos=a), Waypoint(t=5, pos=b)])
    why = scenario_problem(plan.model_copy(update={"trajectories": [through, *plan.trajectories[1:]]}), sc)
    assert why.startswith("UAV 1 segment from waypoint 0 to 1 passes through obstacle 0"), why
    assert "origin" in scenario_problem(plan.model_copy(update={"origin": (0.0, 0.0, 0.0)}), sc)
    assert "UAV(s) [3], not in the mission" in scenario_problem(plan, sc, (1, 2))
    twice = plan.model_copy(update={"trajectories": [*plan.trajectories, plan.trajectories[0]]})
    assert "more than one trajectory for UAV(s) [1]" in scenario_problem(twice, sc)
    cap = plan.captures[0]
    behind = cap.model_copy(update={"look": tuple(-v for v in cap.look)})
    why = scenario_problem(plan.model_copy(update={"captures": [behind, *plan.captures[1:]]}), sc)
    assert f"capture point {cap.capture_id}" in why and "does not face" in why, why
    far = CapturePoint(capture_id=99, uav=1, pos=(500.0, 50.0, 30.0), look=(1.0, 0.0, 0.0), t=1.0)
    assert "capture point 99 at (500.0, 50.0, 30.0) is outside" in scenario_problem(
        plan.model_copy(update={"captures": [*plan.captures, far]}), sc)
    stray = far.model_copy(update={"uav": 9, "pos": cap.pos})
    assert "for UAV 9, which has no trajectory" in scenario_problem(
        plan.model_copy(update={"captures": [stray]}), sc)
