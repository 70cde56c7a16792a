"""services.gcs.figures: the typed figures and series the plots and the Markdown page are drawn from.

The record is test_report's synthetic one (three UAVs on straight lines, 0.5 s late and 0.5 m
off sideways; UAV 3's telemetry stops half-way): its known errors are checked there on the
summary; here, that the series carry the same figures and that nothing depends on the order the
figures are computed in.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.gcs.figures import LinkSamples, ReportFigures, analyse, latency_figures, summarise
from services.recording.record import MissionRecord
from tests.services.gcs.test_report import LAG, SIDE, T_SIM0, V, build_record, timed_error


@pytest.fixture(scope="module")
def record() -> MissionRecord:
    return build_record()


@pytest.fixture(scope="module")
def figs(record) -> ReportFigures:
    return analyse(record)


def test_anchors_are_computed_once_for_every_tracking_uav(figs):
    assert figs.anchors == pytest.approx({1: T_SIM0, 2: T_SIM0, 3: T_SIM0})
    assert {u: f.time_anchor_s for u, f in figs.summary.uavs.items()} == figs.anchors
    assert figs.t0 == pytest.approx(T_SIM0 - 2.0)  # the takeoff state


def test_path_series_hold_the_figures(figs):
    for u, p in figs.paths.items():
        f = figs.summary.uavs[u]
        assert p.t.shape == p.geometric.shape == p.timed.shape == (f.tracking_states,)
        np.testing.assert_allclose(p.geometric, SIDE, atol=1e-9)
        np.testing.assert_allclose(p.timed, timed_error(p.t - T_SIM0), rtol=1e-9)
        assert math.sqrt(np.mean(p.timed**2)) == pytest.approx(f.time_error_rms_m)
    assert figs.paths[3].t[-1] == pytest.approx(T_SIM0 + 10.0)  # UAV 3's telemetry stops half-way


def test_formation_series_flown_and_planned(figs):
    f, s = figs.formation, figs.summary.formation
    assert f.t.size == f.error.size == s.samples
    np.testing.assert_allclose(f.error, math.sqrt(2) / 3, rtol=1e-9)
    # the plan's waypoint times placed on the simulation clock by the anchor
    np.testing.assert_allclose(f.plan_t, T_SIM0 + np.arange(21.0))
    np.testing.assert_allclose(f.plan_error, 0.0, atol=1e-9)


def test_the_figures_do_not_depend_on_the_order_of_the_states(record, figs):
    shuffled = record.model_copy(update={"states": list(reversed(record.states))})
    again = analyse(shuffled)
    assert again.summary.formation == figs.summary.formation
    assert again.anchors == figs.anchors
    np.testing.assert_array_equal(again.formation.plan_t, figs.formation.plan_t)
    for u in (1, 2, 3):
        assert again.summary.uavs[u] == figs.summary.uavs[u]


def test_without_a_plan_there_is_no_anchor_and_no_planned_series(record):
    figs = analyse(record.model_copy(update={"plan": None}))
    assert figs.anchors == {} and figs.paths == {} and figs.trajectories == {}
    assert figs.formation.plan_t is None and figs.formation.t is not None  # the flown shape is still measured
    assert figs.summary.uavs[1].goal_distance_m is None and not figs.summary.uavs[1].reached_goal


def test_link_latencies_come_from_one_set_of_samples(figs):
    lat = figs.latencies
    assert isinstance(lat, LinkSamples)
    for name in ("telemetry", "imagery", "defect_reports", "command"):
        assert figs.summary.links[name].latency_ms == latency_figures(getattr(lat, name))
    np.testing.assert_allclose(lat.telemetry, 0.02)
    np.testing.assert_allclose(lat.imagery, 0.15)
    assert lat.command.size == 6


def test_an_empty_record_has_empty_series():
    figs = analyse(MissionRecord(fleet="empty", speed=1.0, started=0.0))
    assert figs.tracks == {} and figs.paths == {} and figs.anchors == {} and figs.t0 == 0.0
    assert figs.formation.t is None and figs.latencies.telemetry.size == 0
    assert figs.corners == [] and figs.obstacles == []


def test_summarise_is_the_summary_of_analyse(record, figs):
    assert summarise(record) == figs.summary
    assert summarise(record.model_dump(mode="json")).to_dict() == figs.summary.to_dict()
    assert figs.summary.uavs[1].goal_distance_m == pytest.approx(math.hypot(SIDE, V * LAG))


def test_imagery_metrics_merge_the_latest_of_every_detector_instance():
    """two instances (detector-0, detector-1) each report their own cameras; the figures take the
    latest statistics of each, not only of whichever instance spoke last."""
    from protocol.messages import LinkStats
    from services.gcs.figures import _imagery_metrics
    from services.recording.record import StatsRx

    def st(src, stamp, **m):
        return StatsRx(rx=stamp, msg=LinkStats(source=src, stamp=stamp, metrics={k.replace("_", "."): v
                                                                                  for k, v in m.items()}))

    stats = [st("detector-1", 1.0, uav1_cam0_analysed=2), st("detector-0", 2.0, uav2_cam0_analysed=3),
             st("detector-1", 3.0, uav1_cam0_analysed=5)]
    rec = MissionRecord(fleet="f", speed=1.0, started=0.0, detector_stats=stats)
    assert _imagery_metrics(rec) == {"uav1.cam0": {"analysed": 5.0}, "uav2.cam0": {"analysed": 3.0}}


def test_detector_instance_statistics_go_to_the_detector_list():
    from protocol import keys
    from protocol.messages import LinkStats
    from services.recording.load import list_of

    msg = LinkStats(source="detector-1", stamp=1.0)
    assert list_of(keys.rcu_stats("f", "detector-1"), msg) == "detector_stats"
    assert list_of(keys.rcu_stats("f", "planner"), msg) is None


def test_every_gateway_has_its_latest_statistics_in_the_report():
    """--sites: one gateway per site; the summary keeps each one's latest statistics (``gateway``
    stays the latest of any) and the Markdown page has a row per gateway and each one's rejections."""
    from protocol.messages import ClassCounters, LinkStats
    from services.gcs.markdown import markdown
    from services.recording.record import StatsRx

    def st(src, stamp, samples, rejected=None):
        return StatsRx(rx=stamp, msg=LinkStats(source=src, stamp=stamp, uptime_s=stamp, sessions={"peer": 3},
                                               classes={"telemetry": ClassCounters(samples=samples, bytes=100 * samples)},
                                               rejected=rejected or {}))

    stats = [st("gateway/gw0", 1.0, 10), st("gateway/gw1", 2.0, 20, {"unknown-key": 4}), st("gateway/gw0", 3.0, 30)]
    rec = MissionRecord(fleet="f", speed=1.0, started=0.0, gateway_stats=stats)
    s = summarise(rec)
    assert s.gateway["source"] == "gateway/gw0" and s.gateway["classes"]["telemetry"]["samples"] == 30
    assert {k: g["classes"]["telemetry"]["samples"] for k, g in s.gateways.items()} == {"gateway/gw0": 30,
                                                                                          "gateway/gw1": 20}
    md = markdown(rec, s)
    assert "## Gateways" in md and "| gateway/gw1 | peer 3 | 20 |" in md
    assert "Gateway rejections (gateway/gw1): unknown-key: 4." in md


def test_the_links_say_what_the_ground_stations_session_rode_on():
    """In the default secure mode both classes ride TLS streams (no UDP socket): the report used to say
    "UDP: best-effort, drop" for the telemetry there, and a loss on that class is a retransmission delay."""
    secure = summarise(MissionRecord(fleet="f", speed=1.0, started=0.0,
                                     transport={"reliable": "tls", "best-effort": "tls"})).links
    assert "TLS" in secure["telemetry"].carried_as and "UDP" not in secure["telemetry"].carried_as
    assert "TLS" in secure["imagery"].carried_as and secure["command"].carried_as.startswith("TLS")
    plain = summarise(MissionRecord(fleet="f", speed=1.0, started=0.0,
                                    transport={"reliable": "tcp", "best-effort": "udp"})).links
    assert plain["telemetry"].carried_as.startswith("UDP") and plain["command"].carried_as.startswith("TCP")
