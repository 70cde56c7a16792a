"""services.gcs.report: the mission report's figures on a synthetic record with known errors.

The record: three UAVs planned on straight parallel lines along +y (the (P9) slots of a centroid
flying north at 2 m/s for 20 s). Each flies its line 0.5 s late and 0.5 m off sideways (UAV 1
and 2 east, UAV 3 west), so the geometric path error is 0.5 m exactly, the time-aligned error is
hypot(0.5, 2 * min(tau, 0.5)), and the formation shape error is sqrt(2)/3 m (the sideways
offsets about their mean are 1/3, 1/3, -2/3 m). UAV 3's telemetry stops half-way (it does not
reach its goal), UAV 2 loses two telemetry datagrams, UAV 1 has one duplicated.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from edge.geometry.formation import DEFAULT_OFFSETS
from protocol.messages import (
    Box,
    Defect,
    DefectReport,
    Event,
    Level,
    LinkStats,
    MissionPlan,
    Mode,
    Trajectory,
    VehicleState,
    Waypoint,
)
from protocol.scenario import Scenario
from services.gcs.figures import (
    Latency,
    convergence_iteration,
    latency_figures,
    planned_positions,
    polyline_distance,
    shape_errors,
    summarise,
)
from services.gcs.plots import PLOTS
from services.gcs.report import write_report
from services.recording.record import (
    CommandRecord,
    DefectRx,
    EventRx,
    GroundTruthDefect,
    MissionRecord,
    StateRx,
    StatsRx,
)

V, T, LAG, SIDE = 2.0, 20.0, 0.5, 0.5  # m/s, s, s, m
T_SIM0, STAMP0 = 50.0, 1000.0  # sim time and wall time of trajectory time 0
SIDEWAYS = {1: SIDE, 2: SIDE, 3: -SIDE}
SLOTS = {u: np.array([-o[1], o[0], o[2]]) for u, o in zip((1, 2, 3), DEFAULT_OFFSETS)}  # R(pi/2) ΔT_n
CAPTURE_K = (4, 8, 12, 16)
CORNERS = [(5.0, 0.0, 5.0), (5.0, 40.0, 5.0), (5.0, 40.0, 15.0), (5.0, 0.0, 15.0)]  # u = +y, v = +z


def centroid(tau):
    return np.stack([np.zeros_like(tau), V * np.asarray(tau, float), np.full_like(tau, 10.0)], axis=-1)


def wall(u, v):
    return (5.0, u, 5.0 + v)


def build_record() -> MissionRecord:
    taus = np.arange(0, 21) * 1.0
    trajs = [Trajectory(uav=u, waypoints=[
        Waypoint(t=float(tau), pos=tuple(centroid(tau) + SLOTS[u]), yaw=math.pi / 2, speed=V,
                 capture_id=100 * u + k if k in CAPTURE_K else None) for k, tau in enumerate(taus)])
        for u in (1, 2, 3)]
    plan = MissionPlan(algorithm="theta-pso", seed=7, cost=5.0, collision_free=True,
                       centroid_path=[(0, 0, 10), (0, 40, 10)], trajectories=trajs,
                       convergence=[10.0, 8.0, 6.0, 5.001, 5.0], planning_time_s=1.5,
                       geofence=Box(lo=(-20, -10, 0), hi=(20, 50, 30)), origin=(-33.87, 151.19, 0.0))
    states = []
    for u in (1, 2, 3):
        seq = 0
        rows = [(T_SIM0 - 2.0, Mode.TAKEOFF, -1, 0.0, centroid(0.0) + SLOTS[u] + [SIDEWAYS[u], 0, -5])]
        n = 101 if u == 3 else 201
        for i in range(n):
            tau = 0.1 * i
            pos = centroid(max(tau - LAG, 0.0)) + SLOTS[u] + [SIDEWAYS[u], 0, 0]
            rows.append((T_SIM0 + tau, Mode.MISSION, int(tau), tau / T, pos))
        for t, mode, wp, prog, pos in rows:
            if u == 2 and seq in (10, 11):  # lost datagrams
                seq += 1
                continue
            stamp = STAMP0 + (t - T_SIM0)
            msg = VehicleState(uav=u, seq=seq, t=t, stamp=stamp, pos=tuple(pos), vel=(0, V, 0), att=(0, 0, 0),
                               rates=(0, 0, 0), mode=mode, armed=True, wp_index=wp, progress=prog)
            states.append(StateRx(rx=stamp + 0.02, msg=msg))
            if u == 1 and seq == 5:
                states.append(StateRx(rx=stamp + 0.02, msg=msg))  # duplicated datagram
            seq += 1

    def rep(u, cid, *pos, ok=True):
        dd = [Defect(area_px=5, bbox=(0, 0, 1, 5), centroid_px=(0.5, 2.0), contrast=0.5, pos=p) for p in pos]
        s = STAMP0 + cid % 100
        return DefectRx(rx=s + 0.16, msg=DefectReport(uav=u, capture_id=cid, stamp_capture=s, stamp_report=s + 0.15,
                                                     method="it", ok=ok, defects=dd if ok else []))

    defects = [
        rep(1, 104, wall(5.5, 1.2), wall(5.9, 1.4)),  # inside crack 1
        rep(1, 108, wall(20.7, 3.5), None),  # 0.2 m from crack 2, one unplaced
        rep(2, 204, wall(31.5, 0.75)),  # 0.5 m from crack 3: a false positive
        rep(3, 304, wall(12.0, 8.0)),  # nowhere near
        rep(2, 208, ok=False),  # failed: not imaged
        rep(1, 999),  # a capture that was not planned
    ]
    truth = [GroundTruthDefect(id=i, pos=wall((b[0] + b[2]) / 2, (b[1] + b[3]) / 2),
                               uv=((b[0] + b[2]) / 2, (b[1] + b[3]) / 2), bbox_uv=b)
             for i, b in enumerate([(5.0, 1.0, 6.0, 1.5), (20.0, 3.0, 20.5, 4.0), (30.0, 0.5, 31.0, 1.0)], 1)]
    det = [StatsRx(rx=STAMP0 + 5, msg=LinkStats(source="detector", stamp=STAMP0 + 5,
                                                metrics={"uav1.cam0.received": 1.0, "uav1.cam0.lost": 0.0})),
           StatsRx(rx=STAMP0 + 25, msg=LinkStats(source="detector", stamp=STAMP0 + 25, metrics={
               "uav1.cam0.received": 10.0, "uav1.cam0.lost": 2.0, "uav1.cam0.jitter_ms": 3.5,
               "uav2.cam0.received": 8.0, "uav2.cam0.lost": 0.0, "uav2.cam0.jitter_ms": 1.0,
               "queue.dropped": 0.0}))]
    commands = [CommandRecord(uav=u, kind=k, cmd_id=i, ok=not (u == 3 and k == "start"),
                              accepted=not (u == 3 and k == "start"), elapsed_s=0.05, ack_s=[0.01 * (i + 1)])
                for i, (u, k) in enumerate((u, k) for u in (1, 2, 3) for k in ("upload", "start"))]
    events = [EventRx(rx=STAMP0 + 12, msg=Event(source="uav3", stamp=STAMP0 + 12, kind="failsafe",
                                                level=Level.WARNING, text="link lost: hold"))]
    scenario = Scenario.model_validate(
        {"name": "straight", "origin": {"lat": -33.87, "lon": 151.19}, "box": {"lo": [-20, -10, 0], "hi": [20, 50, 40]},
         "start": [0, 0, 10], "goal": [0, 40, 10], "formation": {"offsets": DEFAULT_OFFSETS.tolist()},
         "obstacles": [{"centre": [10.0, 20.0], "radius": 1.0, "height": 12.0}]})
    return MissionRecord(fleet="test", scenario=scenario, speed=1.0, started=STAMP0 - 1, ended=STAMP0 + 30,
                         plan=plan, plan_request_s=2.0, states=states, defects=defects, events=events,
                         detector_stats=det, commands=commands, ground_truth=truth, surface_corners=CORNERS,
                         success=False, failures=["uav 3 did not reach its goal"])


@pytest.fixture(scope="module")
def record() -> MissionRecord:
    return build_record()


@pytest.fixture(scope="module")
def summary(record):
    return summarise(record)


def timed_error(tau):
    return np.hypot(SIDE, V * np.minimum(tau, LAG))


def test_path_error_is_the_known_offset(summary):
    for u in (1, 2, 3):
        f = summary.uavs[u]
        assert f.path_error_rms_m == pytest.approx(SIDE, abs=1e-9)
        assert f.path_error_max_m == pytest.approx(SIDE, abs=1e-9)
        assert f.time_anchor_s == pytest.approx(T_SIM0, abs=1e-9)
        taus = 0.1 * np.arange(101 if u == 3 else 201)
        if u == 2:
            taus = np.delete(taus, [9, 10])  # seqs 10 and 11 were lost (seq 0 is the takeoff state)
        assert f.time_error_rms_m == pytest.approx(np.sqrt(np.mean(timed_error(taus) ** 2)), rel=1e-9)
        assert f.time_error_max_m == pytest.approx(math.hypot(SIDE, V * LAG), rel=1e-9)
    # the takeoff state (5 m below, before MISSION) is not a tracking state
    assert summary.uavs[1].tracking_states == 201 and summary.uavs[1].states == 202


def test_goal_lengths_and_captures(summary):
    f1, f3 = summary.uavs[1], summary.uavs[3]
    assert f1.reached_goal and f1.goal_distance_m == pytest.approx(math.hypot(SIDE, V * LAG))
    assert not f3.reached_goal and f3.goal_distance_m == pytest.approx(math.hypot(SIDE, V * (T - 10 + LAG)))
    assert f1.mission_length_m == pytest.approx(V * (T - LAG))
    assert f1.planned_length_m == pytest.approx(V * T)
    assert f1.path_length_m == pytest.approx(5.0 + V * (T - LAG))  # the climb from the takeoff state
    assert (f1.captures_planned, f1.captures_imaged, summary.uavs[2].captures_imaged) == (4, 2, 1)
    c = summary.captures
    assert (c.planned, c.imaged, c.failed_reports, c.unplanned_reports) == (12, 4, 1, 1)
    assert c.ratio == pytest.approx(4 / 12) and (2, 208) in c.missing


def test_formation_error_is_the_known_shape_error(summary):
    f = summary.formation
    assert f.uavs == [1, 2, 3]
    assert f.rms_m == pytest.approx(math.sqrt(2) / 3, rel=1e-9)
    assert f.max_m == pytest.approx(math.sqrt(2) / 3, rel=1e-9)
    assert f.samples == 101 and f.duration_s == pytest.approx(10.0)  # UAV 3 stops at tau = 10
    assert f.plan_rms_m == pytest.approx(0.0, abs=1e-9) and f.plan_max_m == pytest.approx(0.0, abs=1e-9)


def test_shape_errors_take_the_heading_from_the_motion():
    t = np.arange(0.0, 5.0, 0.1)
    c = np.stack([-1.5 * t, np.zeros_like(t), np.full_like(t, 10.0)], axis=1)  # flying west
    offsets = {u: DEFAULT_OFFSETS[u - 1] for u in (1, 2, 3)}
    west = {u: c + np.array([-o[0], -o[1], o[2]]) for u, o in offsets.items()}  # R(pi) ΔT_n
    np.testing.assert_allclose(shape_errors(t, west, offsets), 0.0, atol=1e-9)
    east = {u: c + offsets[u] for u in offsets}  # the triangle left facing east
    np.testing.assert_allclose(shape_errors(t, east, offsets), math.sqrt((36 + 36) / 3), rtol=1e-9)
    # hovering: no heading from the motion, psi = 0 (east) is used
    still = {u: np.repeat(c[:1], t.size, 0) + offsets[u] for u in offsets}
    np.testing.assert_allclose(shape_errors(t, still, offsets), 0.0, atol=1e-9)
    with pytest.raises(ValueError):
        shape_errors(t, {1: west[1]}, offsets)


def test_defects_by_hand(summary):
    d = summary.defects
    assert (d.n_truth, d.n_found, d.n_reported, d.n_true, d.without_pos) == (3, 2, 5, 3, 1)
    assert d.recall == pytest.approx(2 / 3) and d.precision == pytest.approx(3 / 5)
    assert d.missed_ids == [3] and len(d.false_positives) == 2


def test_links_by_hand(summary):
    tel, img, rep, cmd = (summary.links[k] for k in ("telemetry", "imagery", "defect_reports", "command"))
    assert tel.per_uav[1] == {"received": 202, "sent": 202, "ratio": 1.0}  # duplicate counted once
    assert tel.per_uav[2]["received"] == 200 and tel.per_uav[2]["sent"] == 202
    assert tel.per_uav[3]["ratio"] == 1.0
    assert tel.latency_ms.p50 == pytest.approx(20.0) and tel.latency_ms.p99 == pytest.approx(20.0)
    assert tel.latency_ms.n == 202 + 200 + 102
    assert (img.delivered, img.sent) == (18, 20) and img.ratio == pytest.approx(0.9)  # latest stats only
    assert img.per_uav[1]["jitter_ms"] == 3.5 and img.per_uav[1]["reports"] == 3 and img.per_uav[2]["reports_ok"] == 1
    assert img.latency_ms.n == 5 and img.latency_ms.p50 == pytest.approx(150.0)
    assert rep.latency_ms.p95 == pytest.approx(10.0) and rep.delivered == 6
    assert (cmd.delivered, cmd.sent) == (5, 6) and cmd.ratio == pytest.approx(5 / 6)
    assert cmd.latency_ms.max == pytest.approx(60.0) and cmd.per_uav[3] == {"sent": 2, "ok": 1, "attempts": 2}
    assert summary.imagery["uav1.cam0"]["lost"] == 2.0


def test_planner_and_mission_figures(summary):
    p = summary.planner
    assert (p.initial_cost, p.cost, p.iterations, p.convergence_iteration) == (10.0, 5.0, 4, 3)
    assert p.waypoints == {1: 21, 2: 21, 3: 21} and p.duration_s[2] == pytest.approx(T)
    assert summary.wall_time_s == pytest.approx(31.0)
    assert summary.measured_speed == pytest.approx(1.0)
    assert [e["kind"] for e in summary.events] == ["failsafe"]
    assert not summary.success and summary.failures == ["uav 3 did not reach its goal"]


@pytest.mark.slow
def test_write_report_writes_every_file(record, summary, tmp_path):
    out = write_report(record, tmp_path / "rep")
    names = {p.name for p in (tmp_path / "rep").iterdir()}
    assert names == {"record.json", "report.json", "report.md", *PLOTS} == set(out.files)
    for png in PLOTS:
        assert (tmp_path / "rep" / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert MissionRecord.model_validate_json((tmp_path / "rep" / "record.json").read_text()) == record
    js = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert js["uavs"]["1"]["path_error_rms_m"] == pytest.approx(SIDE)
    assert js["defects"]["recall"] == pytest.approx(2 / 3)
    assert js["links"]["imagery"]["ratio"] == pytest.approx(0.9)
    assert js["links"]["imagery"]["capture_to_report_ms"]["p95"] == pytest.approx(150.0)
    assert js["links"]["telemetry"]["age_ms"]["p50"] == pytest.approx(20.0)
    assert js["mission"]["sim_duration_s"] == pytest.approx(22.0)
    assert js == json.loads(json.dumps(summary.to_dict() | {"files": out.files}))
    md = (tmp_path / "rep" / "report.md").read_text()
    for png in PLOTS:
        assert f"]({png})" in md
    assert "| theta-pso | 10.00 | 5.00 | 3 |" in md and "failsafe" in md


@pytest.mark.slow
def test_an_empty_record_still_gives_a_report(tmp_path):
    rec = MissionRecord(fleet="empty", speed=1.0, started=10.0)
    s = write_report(rec, tmp_path)
    assert s.planner is None and s.uavs == {} and s.defects is None and s.wall_time_s is None
    assert s.formation.rms_m is None and s.links["telemetry"].latency_ms == Latency()
    assert set(s.files) == {p.name for p in tmp_path.iterdir()}
    json.loads((tmp_path / "report.json").read_text())


def test_corners_from_the_scenario_and_no_corners_at_all(record):
    scen = Scenario.model_validate(record.scenario.model_dump() | {"surface": {"corners": CORNERS}})
    s = summarise(record.model_copy(update={"surface_corners": [], "scenario": scen}))
    assert s.defects.recall == pytest.approx(2 / 3) and s.defects.precision == pytest.approx(3 / 5)
    s = summarise(record.model_copy(update={"surface_corners": []}))
    assert s.defects is None and "no surface corners" in s.notes[0]


def test_bad_inputs_are_refused(record, tmp_path):
    with pytest.raises(ValueError, match="MissionRecord"):
        summarise({"fleet": "x"})
    # a record's scenario is typed: a bad one is refused where the record is read, naming the field
    doc = record.model_dump(mode="json")
    for offsets in ([[0, 0]], [[0, 0, 1], [1, 2]], [[0, 0, math.nan]], "abc"):
        bad = dict(doc, scenario=dict(doc["scenario"], formation={"offsets": offsets}))
        with pytest.raises(ValueError, match="offsets"):
            summarise(bad)
    bad = dict(doc, surface_corners=[], scenario=dict(doc["scenario"], surface={"corners": [[0, 0], [1]]}))
    with pytest.raises(ValueError, match="corners"):
        summarise(bad)
    bad = dict(doc, scenario=dict(doc["scenario"], obstacles=[{"centre": [1, 2], "radius": -1, "height": 3}]))
    with pytest.raises(ValueError, match="obstacles"):
        write_report(bad, tmp_path / "obst")
    assert not (tmp_path / "obst").exists()  # refused before anything is written
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match="not a directory"):
        write_report(MissionRecord(fleet="x", speed=1.0, started=0.0), tmp_path / "file")


def test_polyline_distance():
    line = [(0, 0, 0), (2, 0, 0), (2, 2, 0)]
    d = polyline_distance([(1, 1, 0), (3, 3, 0), (-1, 0, 0), (2, 1, 1)], line)
    np.testing.assert_allclose(d, [1.0, math.sqrt(2), 1.0, 1.0])
    np.testing.assert_allclose(polyline_distance([(3, 4, 0)], [(0, 0, 0)]), [5.0])
    assert polyline_distance(np.zeros((0, 3)), line).shape == (0,)
    # a long series against a long line goes in chunks with the same answer
    P = np.random.default_rng(0).uniform(-5, 5, (3000, 3))
    L = np.stack([np.linspace(0, 4, 800), np.sin(np.linspace(0, 4, 800)), np.zeros(800)], axis=1)
    brute = [min(np.linalg.norm(p - L[k] - np.clip((p - L[k]) @ (L[k + 1] - L[k]) / np.sum((L[k + 1] - L[k]) ** 2), 0, 1)
                                * (L[k + 1] - L[k])) for k in range(0, 799)) for p in P[:5]]
    np.testing.assert_allclose(polyline_distance(P, L)[:5], brute)
    with pytest.raises(ValueError):
        polyline_distance([(0, math.nan, 0)], line)
    with pytest.raises(ValueError):
        polyline_distance([(0, 0, 0)], np.zeros((0, 3)))


def test_planned_positions_interpolate_and_clamp():
    tr = Trajectory(uav=1, waypoints=[Waypoint(t=1.0, pos=(0, 0, 0)), Waypoint(t=3.0, pos=(2, 4, 6))])
    np.testing.assert_allclose(planned_positions(tr, [0.0, 2.0, 5.0]), [[0, 0, 0], [1, 2, 3], [2, 4, 6]])
    with pytest.raises(ValueError):
        planned_positions(tr, [math.inf])


def test_latency_and_convergence_helpers():
    lat = latency_figures([0.001 * k for k in range(1, 101)] + [math.nan])
    assert lat.n == 100 and lat.p50 == pytest.approx(50.5) and lat.max == pytest.approx(100.0)
    assert lat.p99 == pytest.approx(99.01)
    assert latency_figures([]) == Latency()
    assert convergence_iteration([3.0, 3.0, 3.0]) == 0
    assert convergence_iteration([]) is None
    with pytest.raises(ValueError):
        convergence_iteration([1.0, math.nan])


def test_edges_with_their_own_epochs_give_the_same_figures():
    """under docker compose each edge's sim clock starts at its own container start. The
    same flight with UAV 2's clock 1.25 s and UAV 3's 0.6 s of sim time ahead (same wall stamps) must
    give the figures of the shared-epoch record, not a formation error of metres."""
    rec = build_record()
    skew = {1: 0.0, 2: 1.25, 3: 0.6}
    states = [s.model_copy(update={"msg": s.msg.model_copy(update={"t": s.msg.t + skew[s.msg.uav]})})
              for s in rec.states]
    skewed = summarise(rec.model_copy(update={"states": states}))
    base = summarise(rec)
    assert skewed.formation.rms_m == pytest.approx(base.formation.rms_m, abs=1e-6)
    assert skewed.formation.max_m == pytest.approx(base.formation.max_m, abs=1e-6)
    for u in (1, 2, 3):
        assert skewed.uavs[u].path_error_rms_m == pytest.approx(base.uavs[u].path_error_rms_m, abs=1e-6)


def test_the_capture_figure_counts_only_captures_held_when_the_record_says_which(record, summary):
    """Without ``held_captures`` (no mission log) every ok report counts and the figure says it was not checked;
    with it, only those captures (the verdict's, checked against the frames the ground station received)."""
    from services.gcs.markdown import markdown

    assert not summary.captures.checked and summary.captures.imaged == 4
    assert "not checked against the frames" in markdown(record, summary)
    held = record.model_copy(update={"held_captures": [(1, 104)]})
    checked = summarise(held)
    assert checked.captures.checked and checked.captures.imaged == 1 and checked.uavs[1].captures_imaged == 1
    assert "on a frame the ground station received itself): 1 of 12" in markdown(held, checked)
