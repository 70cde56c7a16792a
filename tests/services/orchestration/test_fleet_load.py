"""The launcher's fleet-size defaults: the ground station's state feed, previews, the edges' priority."""

import json

import pytest

from services.orchestration.fleet_load import EDGE_NICE, GCS_STATE_BUDGET, NICE_ABOVE, PREVIEW_BUDGET, fleet_load


def test_the_papers_fleet_keeps_every_state_full_previews_and_equal_priority():
    for n in (1, 3, 6, 12):
        load = fleet_load(n)
        assert load.gcs_state_hz == 0.0 and load.edge_nice == 0
        assert load.preview_hz == min(2.0, PREVIEW_BUDGET / n)
    assert fleet_load(3).chosen == ()


@pytest.mark.parametrize("n", [13, 24, 48, 100, 255])
def test_a_large_fleet_shares_fixed_budgets_and_yields_to_the_services(n):
    load = fleet_load(n)
    assert load.gcs_state_hz * n == pytest.approx(GCS_STATE_BUDGET)
    assert load.preview_hz * n == pytest.approx(PREVIEW_BUDGET)
    assert load.edge_nice == (EDGE_NICE if n > NICE_ABOVE else 0)
    said = " ".join(load.chosen)
    assert "--gcs-state-hz" in said and "--preview-hz" in said and "--edge-nice" in said


def test_a_given_value_is_kept_whatever_the_fleet():
    load = fleet_load(48, gcs_state_hz=0.0, preview_hz=2.0, edge_nice=0)
    assert (load.gcs_state_hz, load.preview_hz, load.edge_nice, load.chosen) == (0.0, 2.0, 0, ())
    load = fleet_load(3, gcs_state_hz=5.0, preview_hz=0.0, edge_nice=10)
    assert (load.gcs_state_hz, load.preview_hz, load.edge_nice) == (5.0, 0.0, 10)


@pytest.mark.parametrize("kw", [{"uavs": 0}, {"uavs": 256}, {"uavs": True}, {"uavs": 3.0},
                                {"uavs": 3, "gcs_state_hz": -1.0}, {"uavs": 3, "gcs_state_hz": float("nan")},
                                {"uavs": 3, "preview_hz": float("inf")}, {"uavs": 3, "preview_hz": "2"},
                                {"uavs": 3, "edge_nice": 20}, {"uavs": 3, "edge_nice": -1},
                                {"uavs": 3, "edge_nice": 1.5}, {"uavs": 3, "edge_nice": True}])
def test_bad_values_are_refused(kw):
    with pytest.raises(ValueError):
        fleet_load(**kw)


def test_the_launcher_applies_them_to_the_edges_and_the_gateway():
    """No process started: the edges' options and the gateway's downsampling rules of a 13-UAV network."""
    from services.orchestration.launcher import Network, parse

    net = Network(parse("up", ["--fleet", "load", "--uavs", "13"]), echo=None)
    try:
        assert net.load == fleet_load(13)
        (key, value), = net.layout.get("gateway").config.cfg
        rules = json.loads(value)[0]["rules"]
        assert key == "downsampling" and f"--cfg=downsampling:{value}" in net.layout.get("gateway").argv
        assert len(rules) == 13 and all(r["freq"] == pytest.approx(GCS_STATE_BUDGET / 13) for r in rules)
    finally:
        net.stop()
    net = Network(parse("up", ["--fleet", "load", "--uavs", "13", "--gcs-state-hz", "0",
                                                 "--edge-nice", "0", "--preview-hz", "2"]), echo=None)
    try:
        assert (net.load.gcs_state_hz, net.load.edge_nice, net.load.preview_hz) == (0.0, 0, 2.0)
        assert net.layout.get("gateway").config.cfg == []
    finally:
        net.stop()
    for bad in ("20", "-1", "x"):
        with pytest.raises(SystemExit):
            parse("up", ["--edge-nice", bad])
