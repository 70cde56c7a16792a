"""Tests of the planner's pure core: scenario, task assessment (P1-P3), cost (P5), θ-PSO (P4),
baselines, formation trajectories (P6-P9), export, plan_mission and the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from services.planner.cli import main as cli_main
from services.planner.compare import compare, convergence_plot
from services.planner.cost import Cost, PathProblem, clearance, path_collision_free, point_segment_distance
from services.planner.export import (
    MAV_CMD_DO_DIGICAM_CONTROL,
    MAV_CMD_NAV_RETURN_TO_LAUNCH,
    MAV_CMD_NAV_TAKEOFF,
    mission_geojson,
    parse_geojson,
    parse_qgc_wpl,
    qgc_wpl,
    waypoints_enu,
)
from services.planner.mission import optimise, plan_details, plan_mission
from services.planner.scenario import Camera, Scenario, ScenarioError, load_scenario, validate_scenario
from services.planner.task import camera_grid, coverage, footprint, formation_pass, spacing, standoff
from services.planner.theta_pso import inverse_sine_map, sine_map, theta_pso

SC = load_scenario()


def _doc(**changes):
    d = SC.model_dump(mode="python")
    d.update(changes)
    return d


def _no_obstacles(**changes) -> Scenario:
    return validate_scenario(_doc(obstacles=[], surface=None, **changes))


# ----------------------------------------------------------------------------- scenario
def test_default_scenario_is_the_paper_setting():
    assert SC.box.hi == (101.0, 141.0, 40.0)
    assert SC.start == (40.0, 8.0, 30.0) and SC.goal == (64.0, 108.0, 34.0)
    assert len(SC.obstacles) == 10 and len({c.radius for c in SC.obstacles}) == 10
    assert (SC.origin.lat, SC.origin.lon) == (-33.87601, 151.191182)


def test_default_scenario_blocks_the_straight_line():
    assert not path_collision_free(np.array([SC.start, SC.goal]), SC)


@pytest.mark.parametrize(
    "change, field",
    [
        ({"start": (40.0, 200.0, 30.0)}, "start"),
        ({"obstacles": [{"centre": (1.0, 1.0), "radius": -1.0, "height": 5.0}]}, "obstacles[0].radius"),
        ({"camera": {"resolution": (4000, 3000), "sensor_mm": (36.0, math.nan), "focal_mm": 34.4}}, "camera.sensor_mm"),
        ({"inspection": {"overlap": 1.5}}, "inspection.overlap"),
        ({"goal": (64.0, 108.0)}, "goal"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_scenario_errors_name_the_field(change, field):
    with pytest.raises(ScenarioError) as ei:
        validate_scenario(_doc(**change))
    assert field in str(ei.value)
    assert isinstance(ei.value, ValueError)


def test_scenario_file_errors(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("start = [1, 2\n")
    with pytest.raises(ScenarioError, match="not valid TOML"):
        load_scenario(bad)
    with pytest.raises(ScenarioError, match="cannot read"):
        load_scenario(tmp_path / "missing.toml")
    bad.write_text('name = "x"\n[origin]\nlat = 0\nlon = 0\n[box]\nlo = [0,0,0]\nhi = [10,10,10]\n')
    with pytest.raises(ScenarioError, match="'start'"):
        load_scenario(bad)


def test_surface_must_be_a_vertical_rectangle():
    with pytest.raises(ScenarioError, match="surface.corners"):
        validate_scenario(_doc(surface={"corners": [(60, 85, 25), (60, 35, 25), (60, 35, 31), (60, 80, 31)]}))
    with pytest.raises(ScenarioError, match="vertical"):
        validate_scenario(_doc(surface={"corners": [(50, 40, 20), (60, 40, 20), (60, 50, 20), (50, 50, 20)]}))


# ----------------------------------------------------------------------------- task assessment
def test_task_assessment_hand_numbers():
    cam = Camera(resolution=(4000, 3000), sensor_mm=(36.0, 27.0), focal_mm=34.4)
    # (P1) a = 1/2 * 4000 px * 2.5 mm = 5 m; 1/2 * 3000 * 2.5 mm = 3.75 m
    assert footprint(cam, 0.0025) == pytest.approx((5.0, 3.75))
    # (P2) d = 5 m * 34.4 mm / 36 mm = 4.7778 m (the same on the 27 mm axis: square pixels)
    assert standoff(cam, 0.0025) == pytest.approx(4.777777, rel=1e-6)
    # (P3) g = (1 - 0.2) * 5 m = 4 m
    assert spacing(5.0, 0.2) == pytest.approx(4.0)
    # the real GoPro sensor: 6.17 mm wide, ~2.92 mm focal length -> d = 5 * 2.92 / 6.17 = 2.366 m
    real = Camera(resolution=(4000, 3000), sensor_mm=(6.17, 4.55), focal_mm=2.92)
    assert standoff(real, 0.0025) == pytest.approx(min(5 * 2.92 / 6.17, 3.75 * 2.92 / 4.55))
    with pytest.raises(ValueError):
        footprint(cam, -1.0)
    with pytest.raises(ValueError):
        spacing(5.0, 1.0)


def test_camera_grid_covers_the_wall_at_the_standoff():
    pos, look = camera_grid(SC.surface, SC.camera, 0.0025, 0.2)
    p0, _, n = SC.surface.frame
    # 50 m wall, 5 m footprint, 4 m spacing: ceil(45 / 4) + 1 = 13 columns; 6 m tall: 2 rows
    assert pos.shape == (26, 3)
    assert np.allclose((pos - p0) @ n, 4.777777, atol=1e-6)
    assert coverage(SC.surface, SC.camera, pos, look) == 1.0
    assert coverage(SC.surface, SC.camera, pos[::2], look[::2]) < 1.0


def test_formation_pass_images_the_whole_wall():
    ip = formation_pass(SC)
    assert ip is not None and ip.uav.size == 26
    assert coverage(SC.surface, SC.camera, ip.positions, ip.look) == 1.0
    assert set(ip.uav.tolist()) == {0, 1, 2}
    assert np.all(np.diff(ip.leg_s) >= 0) and np.all(ip.leg_s > 0) and np.all(ip.leg_s < ip.length)


def test_formation_pass_rejects_a_wall_too_tall():
    tall = [(60, 85, 20), (60, 35, 20), (60, 35, 35), (60, 85, 35)]
    with pytest.raises(ValueError, match="tall"):
        formation_pass(validate_scenario(_doc(surface={"corners": tall})))


# ----------------------------------------------------------------------------- cost and θ-PSO maps
def test_sine_map_bounds_and_inverse():
    lo, hi = np.array([0.0, -5.0, 10.0]), np.array([101.0, 5.0, 40.0])
    th = np.random.default_rng(0).uniform(-np.pi / 2, np.pi / 2, (1000, 3))
    x = sine_map(th, lo, hi)
    assert np.all(x >= lo) and np.all(x <= hi)
    assert np.allclose(sine_map(-np.pi / 2, lo, hi), lo) and np.allclose(sine_map(np.pi / 2, lo, hi), hi)
    assert np.allclose(inverse_sine_map(x, lo, hi), th)


def test_point_segment_distance_analytic():
    a, b = np.array([0.0, 0.0]), np.array([10.0, 0.0])
    assert point_segment_distance([5.0, 3.0], a, b) == pytest.approx(3.0)  # perpendicular foot inside
    assert point_segment_distance([-3.0, 4.0], a, b) == pytest.approx(5.0)  # beyond a
    assert point_segment_distance([13.0, -4.0], a, b) == pytest.approx(5.0)  # beyond b
    assert point_segment_distance([1.0, 1.0], a, a) == pytest.approx(math.sqrt(2))  # degenerate
    p = np.array([[1.0, 2.0, 2.0]])
    assert point_segment_distance(p, [0, 0, 0], [2, 0, 0])[0] == pytest.approx(math.sqrt(8))


def test_straight_line_cost_without_obstacles_is_the_distance():
    sc = _no_obstacles()
    cost = Cost(PathProblem.from_scenario(sc, 3))
    V = np.array([sc.start, sc.goal], float)[None]
    J = cost.path_terms(V)[0]
    assert J[0] == pytest.approx(102.92, abs=0.005)
    assert J[1] == 0.0 and J[2] == 0.0
    # free waypoints on the straight line: same cost, through the vectorised entry point
    x = np.linspace(sc.start, sc.goal, 5)[1:-1].reshape(1, -1)
    assert cost(x)[0] == pytest.approx(102.917, abs=1e-3)


def test_collision_penalty_grows_with_depth_and_is_finite():
    sc = validate_scenario(_doc(surface=None, obstacles=[{"centre": (52.0, 58.0), "radius": 4.0, "height": 40.0}]))
    cost = Cost(PathProblem.from_scenario(sc, 1))
    base = np.array([52.0, 58.0, 32.0])
    xs = np.array([base + [d, 0, 0] for d in (12.0, 5.5, 3.0, 1.0, 0.0)])
    J2 = cost.terms(xs)[:, 1]
    assert np.all(np.isfinite(J2))
    assert J2[0] == 0.0 and 0 < J2[1] < J2[2] < J2[3] < J2[4]
    assert J2[2] > sc.cost.collision_penalty  # inside: the large penalty
    with pytest.raises(ValueError):
        cost(np.full((1, 3), np.nan))


def _reference_terms(V, sc, problem):
    """J1, J2, J3 (P5) of one centroid polyline, written out loop by loop from cost.py's definitions."""
    K, D, r_uav = sc.cost.collision_penalty, sc.cost.danger_band, sc.cost.uav_radius
    off, cyl = sc.offsets, sc.cylinders()
    p0, u, n = sc.surface.frame
    Lw, (z0, z1) = sc.surface.length, sc.surface.z_range
    keep = 0.9 * problem.inspection.standoff
    lo, hi = sc.cost.altitude
    dmin = sc.formation.min_separation
    short = sum(max((dmin - np.linalg.norm(off[i] - off[j])) / dmin, 0.0)
                for i in range(len(off)) for j in range(i + 1, len(off)))
    J1 = J2 = J3 = 0.0
    for s_ in range(len(V) - 1):
        a, b = V[s_], V[s_ + 1]
        d = b - a
        J1 += np.linalg.norm(d)
        J2 += K * short
        yaw = math.atan2(d[1], d[0])
        R = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
        if s_ + 1 < len(V) - 1:
            e = V[s_ + 2] - b
            h1, h2 = np.hypot(*d[:2]), np.hypot(*e[:2])
            if h1 > 1e-9 and h2 > 1e-9:
                turn = math.acos(np.clip((d[0] * e[0] + d[1] * e[1]) / (h1 * h2), -1, 1))
                J2 += 0.1 * K * max(turn - np.deg2rad(sc.cost.max_turn_deg), 0.0)
        for o in off:
            A, B = a + R @ o, b + R @ o
            dd = (B - A)[:2] @ (B - A)[:2]
            for cx, cy, r, h in cyl:
                t = 0.0 if dd == 0 else float(np.clip(((np.array([cx, cy]) - A[:2]) @ (B - A)[:2]) / dd, 0, 1))
                q = A + t * (B - A)
                gap = math.hypot(cx - q[0], cy - q[1]) - r
                c = (gap if q[2] <= h else math.hypot(max(gap, 0.0), q[2] - h)) - r_uav
                J2 += 1.0 + K * (1.0 - c) if c < 0 else min(max((D - c) / D, 0.0), 1.0) ** 2
            qa, qb = (A - p0) @ n, (B - p0) @ n
            if qa * qb < 0:
                t = qa / (qa - qb)
                X = A + t * (B - A)
                su = (X - p0) @ u
                depth = min(su, Lw - su, X[2] - z0, z1 - X[2])
                if depth > -r_uav:
                    J2 += K * (1.0 + max(depth, 0.0))
            for k in (np.arange(8) + 0.5) / 8:
                Q = A + k * (B - A)
                su = (Q - p0) @ u
                near = p0 + min(max(su, 0.0), Lw) * u
                near[2] = min(max(Q[2], z0), z1)
                J3 += max((keep - np.linalg.norm(Q - near)) / keep, 0.0)
            for z in ([A[2], B[2]] if s_ == len(V) - 2 else [A[2]]):
                J3 += 0.1 * K * (max(lo - z, 0.0) + max(z - hi, 0.0))
    return np.array([J1, J2, J3])


LATERAL = validate_scenario(_doc(formation={"offsets": [(0.0, 1.5, 2.0), (3.0, 1.5, -1.0), (-2.0, 1.5, -1.0)],
                                          "min_separation": 2.0}))


@pytest.mark.parametrize("sc", [SC, LATERAL], ids=["default", "lateral-offsets"])
def test_vectorised_cost_equals_the_loop_reference(sc):
    problem = PathProblem.from_scenario(sc, 4)
    cost = Cost(problem)
    rng = np.random.default_rng(7)
    X = np.concatenate([problem.initial_population(12, rng, "box"), problem.initial_population(12, rng)])
    W = X.reshape(-1, 4, 3)
    W[0, 1] = W[0, 0]  # repeated point: zero-length segment
    W[1, 1, :2] = W[1, 0, :2]  # vertical segment
    W[2, :, 2] = 39.5  # over the tops of the 35 m and 38 m posts
    W[3, 0] = [48.0, 45.0, 20.0]  # inside the lamp post
    W[4, 0], W[4, 1] = [55.0, 60.0, 28.0], [66.0, 60.0, 28.0]  # through the girder wall
    got = cost.terms(X)
    V = problem.assemble(X)
    want = np.array([_reference_terms(v, sc, problem) for v in V])
    assert np.allclose(got, want, rtol=1e-9, atol=1e-9)
    assert want[3, 1] > sc.cost.collision_penalty and want[4, 1] > sc.cost.collision_penalty
    assert np.count_nonzero(want[:, 2] > 0) >= 10  # the stand-off and altitude terms are exercised


def test_clearance_of_points():
    sc = validate_scenario(_doc(surface=None, obstacles=[{"centre": (10.0, 10.0), "radius": 2.0, "height": 20.0}]))
    r = sc.cost.uav_radius
    c = clearance(np.array([[15.0, 10.0, 5.0], [10.0, 10.0, 23.0], [11.0, 10.0, 5.0]]), sc)
    assert c == pytest.approx([3.0 - r, 3.0 - r, -1.0 - r])


# ----------------------------------------------------------------------------- optimisers
def test_seeded_runs_are_reproducible():
    a = optimise(SC, "theta-pso", seed=3, particles=20, iterations=15)[1]
    b = optimise(SC, "theta-pso", seed=3, particles=20, iterations=15)[1]
    c = optimise(SC, "theta-pso", seed=4, particles=20, iterations=15)[1]
    assert np.array_equal(a.x, b.x) and a.cost == b.cost
    assert not np.array_equal(a.x, c.x)


@pytest.mark.parametrize("algorithm", ["theta-pso", "pso", "ga", "tlbo"])
def test_every_algorithm_keeps_the_budget_and_improves(algorithm):
    problem, res = optimise(SC, algorithm, seed=1, particles=30, iterations=40)
    assert res.evaluations == 30 * 41
    assert res.history.shape == (41,)
    assert np.all(np.diff(res.history) <= 0)
    assert res.cost < res.initial_cost
    assert np.all(res.x >= np.tile(problem.lo, 10) - 1e-9) and np.all(res.x <= np.tile(problem.hi, 10) + 1e-9)


def test_same_initialisation_for_all_algorithms():
    inits = {a: optimise(SC, a, seed=2, particles=20, iterations=2)[1].initial_cost for a in ("theta-pso", "pso", "ga", "tlbo")}
    assert len(set(inits.values())) == 1


def test_theta_pso_settings_are_checked_and_both_draws_work():
    problem = PathProblem.from_scenario(SC, 10)
    x0 = problem.initial_population(12, np.random.default_rng(0))
    with pytest.raises(ValueError, match="dtheta_max"):
        theta_pso(Cost(problem), x0, 3, np.random.default_rng(1), dtheta_max=2.0)
    for per_dimension in (True, False):
        res = theta_pso(Cost(problem), x0, 20, np.random.default_rng(1), per_dimension=per_dimension)
        assert res.evaluations == 12 * 21 and res.cost < res.initial_cost


def test_theta_pso_ends_collision_free_on_the_default_scenario():
    problem, res = optimise(SC, "theta-pso", seed=0, particles=60, iterations=80)
    assert res.cost < 0.7 * res.initial_cost
    assert path_collision_free(problem.assemble(res.x[None])[0], SC)


# ----------------------------------------------------------------------------- plan, trajectories
@pytest.fixture(scope="module")
def plan_and_traj():
    plan, ft, _ = plan_details(SC, seed=0, particles=60, iterations=100)
    return plan, ft


def test_plan_mission_trajectories_and_captures(plan_and_traj):
    plan, ft = plan_and_traj
    assert plan.collision_free and ft.min_clearance >= 0
    assert len(plan.trajectories) == 3 and [t.uav for t in plan.trajectories] == [1, 2, 3]
    assert 55.0 <= ft.duration_s <= 180.0  # about 1-3 min: a ~113 m path at 2 m/s is just under 60 s
    assert len(plan.captures) == 26
    by_uav = {t.uav: t for t in plan.trajectories}
    p0, u, n = SC.surface.frame
    for c in plan.captures:
        wp = [w for w in by_uav[c.uav].waypoints if w.capture_id == c.capture_id]
        assert len(wp) == 1  # the capture point is a waypoint of its UAV's trajectory
        assert np.allclose(wp[0].pos, c.pos) and wp[0].t == c.t
        assert (np.asarray(c.pos) - p0) @ n == pytest.approx(plan.standoff_m, abs=0.01)
        assert np.allclose(c.look, -n)
        assert math.cos(wp[0].yaw - math.atan2(c.look[1], c.look[0])) > 0.999  # facing the wall
    assert coverage(SC.surface, SC.camera, [c.pos for c in plan.captures], [c.look for c in plan.captures]) == 1.0
    # speed limits and the centroid (P6)
    for t in plan.trajectories:
        P = np.array([w.pos for w in t.waypoints])
        T = np.array([w.t for w in t.waypoints])
        assert np.max(np.linalg.norm(np.diff(P, axis=0), axis=1) / np.diff(T)) <= SC.speeds.max + 1e-9
        assert np.allclose(P[0], np.asarray(SC.start) + [[0, 0, 2], [0, 0, -1], [0, 0, -1]][t.uav - 1], atol=3.5)
    assert np.allclose(ft.positions.mean(axis=1), ft.centroid, atol=1e-9)
    assert np.allclose(ft.centroid[0], SC.start) and np.allclose(ft.centroid[-1], SC.goal)


def test_plan_mission_rejects_bad_requests():
    with pytest.raises(ValueError, match="algorithm"):
        plan_mission(SC, algorithm="simplex")
    with pytest.raises(ValueError, match="particles"):
        plan_mission(SC, particles=1)
    with pytest.raises(ValueError, match="box.lo|box"):
        plan_mission(_doc(box={"lo": (0, 0, 0), "hi": (0, 141, 40)}))


def test_plan_mission_accepts_a_scenario_dict():
    plan = plan_mission(SC.model_dump(mode="json"), seed=1, particles=10, iterations=3)
    assert plan.seed == 1 and len(plan.convergence) == 4


# ----------------------------------------------------------------------------- export
def test_waypoint_file_round_trip(plan_and_traj):
    plan, _ = plan_and_traj
    for tr in plan.trajectories:
        items = parse_qgc_wpl(qgc_wpl(tr, plan.origin))
        assert items[1].command == MAV_CMD_NAV_TAKEOFF and items[-1].command == MAV_CMD_NAV_RETURN_TO_LAUNCH
        enu, caps = waypoints_enu(items)
        P = np.array([w.pos for w in tr.waypoints])
        assert enu.shape == P.shape and np.max(np.abs(enu - P)) < 0.01
        assert caps == [w.capture_id for w in tr.waypoints]
        assert sum(it.command == MAV_CMD_DO_DIGICAM_CONTROL for it in items) == sum(c is not None for c in caps)


def test_geojson_round_trip(plan_and_traj):
    plan, _ = plan_and_traj
    doc = json.loads(json.dumps(mission_geojson(plan)))
    lines = parse_geojson(doc, plan.origin)
    assert np.max(np.abs(lines["centroid"] - np.array(plan.centroid_path))) < 0.01
    P = np.array([w.pos for w in plan.trajectories[1].waypoints])
    assert np.max(np.abs(lines["uav2"] - P)) < 0.01
    assert sum(f["properties"]["kind"] == "capture" for f in doc["features"]) == 26


def test_parsers_reject_garbage():
    with pytest.raises(ValueError, match="QGC WPL 110"):
        parse_qgc_wpl("hello\n")
    with pytest.raises(ValueError, match="line 2"):
        parse_qgc_wpl("QGC WPL 110\n0\t1\t0\t16\n")
    with pytest.raises(ValueError):
        parse_geojson({"type": "Feature"}, (0.0, 0.0, 0.0))


# ----------------------------------------------------------------------------- compare and CLI
def test_compare_table_and_plot(tmp_path):
    res = compare(SC, seeds=2, particles=12, iterations=6)
    assert set(res["rows"]) == {"ga", "tlbo", "pso", "theta-pso"}
    for r in res["rows"].values():
        assert r["final_best"] <= r["final_mean"] <= r["initial_cost"]
        assert 0.0 <= r["collision_free"] <= 1.0 and 0 <= r["convergence_iteration"] <= 6
    png = convergence_plot(res, tmp_path / "conv.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_plan_writes_files(tmp_path, capsys):
    rc = cli_main(["mission", "--seed", "0", "--particles", "60", "--iterations", "100", "--out", str(tmp_path)])
    assert rc == 0
    assert (tmp_path / "uav1.waypoints").read_text().startswith("QGC WPL 110")
    assert json.loads((tmp_path / "mission.geojson").read_text())["type"] == "FeatureCollection"
    assert "collision-free" in capsys.readouterr().out
    assert cli_main(["mission", "--scenario", str(tmp_path / "nope.toml")]) == 2


def test_scenario_file_that_is_not_utf8_is_a_scenario_error(tmp_path):
    """Fuzzing found that bytes that are not UTF-8 let UnicodeDecodeError escape the loader."""
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(b'name = "caf\xe9"\n')
    with pytest.raises(ScenarioError, match="not UTF-8"):
        load_scenario(bad)


# ----------------------------------------------------------------------------- fleets of several formations
def test_a_fleet_of_24_in_stacked_rows_is_planned_inside_the_box_and_images_the_wall():
    """24 UAVs (eight formations of three) planned as one stacked fleet: every trajectory
    inside the box, the top two rows take every shot at the stand-off, the rows below take none,
    no two UAVs closer than the lattice pitch, every UAV above the altitude band's floor."""
    from edge.geometry.formation import ROW_PITCH_M, offsets_for
    from services.gcs.preflight import plan_problem
    from services.planner.task import imaging_rows

    off = offsets_for(24)
    sc = validate_scenario(_doc(formation={"offsets": [tuple(o) for o in off], "min_separation": 2.0}))
    ip = formation_pass(sc)
    assert ip is not None and ip.uav.size == 26  # the same 26 shots as the paper's three
    assert coverage(SC.surface, SC.camera, ip.positions, ip.look) == 1.0
    assert set(np.unique(off[ip.uav, 2])) == {2.0, -1.0}  # only the two imaging rows shoot
    np.testing.assert_array_equal(imaging_rows(off[:, 2], 6.0, 3.75), [-1.0, 2.0])
    np.testing.assert_array_equal(imaging_rows([2.0, -1.0], 6.0, 3.75), [-1.0, 2.0])  # the paper's: both rows
    plan, ft, _ = plan_details(sc, particles=60, iterations=60)
    assert len(plan.trajectories) == 24 and len(plan.captures) == 26
    assert plan_problem(plan, sc.formation.offsets) == ""  # fits the box (the line of 24 did not)
    assert plan.collision_free and ft.min_clearance > 0
    P = ft.positions  # (samples, 24, 3)
    d = np.linalg.norm(P[:, :, None] - P[:, None], axis=-1) + np.eye(24) * 99
    assert d.min() >= ROW_PITCH_M - 0.01
    assert P[..., 2].min() >= SC.cost.altitude[0] - 1e-6


def test_imaging_rows_fall_back_to_every_row_for_a_wall_too_tall():
    from services.planner.task import imaging_rows

    np.testing.assert_array_equal(imaging_rows([2.0, -1.0, -3.5], 20.0, 3.75), [-3.5, -1.0, 2.0])


def test_cost_of_a_stacked_fleet_looks_at_fewer_uavs_with_the_same_zero_set(monkeypatch):
    """services.planner.cost.cost_offsets: 48 UAVs cost as 28, the paper's three are unchanged, and
    on a real swarm the reduced cost is clear of obstacles exactly where the full one is."""
    import services.planner.cost as cost_mod
    from edge.geometry.formation import offsets_for
    from services.planner.cost import cost_offsets

    np.testing.assert_array_equal(cost_offsets(offsets_for(3), 6.0), offsets_for(3))
    red = cost_offsets(offsets_for(48), 6.0)
    assert len(red) == 28
    for x in np.unique(red[:, 0]):  # each column: its top and bottom, kept rows at most the wall's height apart
        z = np.sort(red[red[:, 0] == x, 2])
        col = offsets_for(48)[offsets_for(48)[:, 0] == x, 2]
        assert z[0] == col.min() and z[-1] == col.max() and np.all(np.diff(z) <= 6.0)
    sc = validate_scenario(_doc(formation={"offsets": [tuple(o) for o in offsets_for(48)], "min_separation": 2.0}))
    pb = PathProblem.from_scenario(sc, 10)
    _, res = optimise(sc, particles=60, iterations=60)  # one path clear of every obstacle ...
    x = np.vstack([pb.initial_population(150, np.random.default_rng(0), "corridor", 15.0), res.x])  # ... and 150 not
    reduced = Cost(pb)
    monkeypatch.setattr(cost_mod, "cost_offsets", lambda off, h: np.asarray(off, float))
    full = Cost(pb)
    assert full.off.shape[0] == 48 and reduced.off.shape[0] == 28
    jf, jr = full.terms(x), reduced.terms(x)
    np.testing.assert_array_equal(jf[:, 0], jr[:, 0])  # J1: the centroid's length
    assert np.all(jr[:, 1:] <= jf[:, 1:] + 1e-9)  # a subset of the UAVs' terms
    hit_f, hit_r = jf[:, 1] >= sc.cost.collision_penalty, jr[:, 1] >= sc.cost.collision_penalty
    assert 0 < np.count_nonzero(hit_f) < len(x)  # the swarm has paths into obstacles and paths clear of them
    np.testing.assert_array_equal(hit_f, hit_r)  # ... and the reduced cost sees the same ones
