"""The experiment grid, per-run figures, per-cell aggregation and the table (pure)."""

import json

import pytest

from services.experiment.grid import (
    Cell,
    check_links,
    expand,
    impair_spec,
    mission_command,
    parse_list,
    parse_recovery,
    plan,
)
from services.experiment.metrics import METRICS, aggregate, run_metrics
from services.experiment.table import markdown


def test_lists_parse_and_bad_lists_say_why():
    assert parse_list("0, 5,20,40", "--loss-pct", hi=100) == (0.0, 5.0, 20.0, 40.0)
    assert parse_recovery("on,off") == (True, False) and parse_recovery("OFF") == (False,)
    for text, what in [("", "comma-separated"), ("5,x", "'x' is not a number"), ("-1", "in 0..100"),
                       ("101", "in 0..100"), ("nan", "finite"), ("5,5", "twice"), ("1,,2", "'' is not")]:
        with pytest.raises(ValueError, match=what):
            parse_list(text, "--loss-pct", hi=100)
    for bad in ("", "yes", "on,on", "on;off"):
        with pytest.raises(ValueError, match="--recovery"):
            parse_recovery(bad)


def test_grid_is_the_product_and_runs_share_seeds_across_cells():
    cells = expand((0, 5, 20, 40), (0, 50, 200))
    assert len(cells) == 12 and len(set(cells)) == 12
    assert {c.loss_pct for c in cells} == {0, 5, 20, 40} and {c.delay_ms for c in cells} == {0, 50, 200}
    assert all(c.recovery and c.jitter_ms == 0 for c in cells)
    both = expand((20,), (200,), (0,), (True, False))
    assert [c.recovery for c in both] == [True, False]  # with/without side by side
    runs = plan(cells, repeat=3, seed=10)
    assert len(runs) == 36
    assert [r.seed for r in runs[:12]] == [10] * 12 and runs[12].seed == 11 and runs[-1].seed == 12
    assert runs[:12] == plan(cells, 1, 10)  # repeat-major: the first pass covers every cell
    assert len({r.name for r in runs}) == 36
    with pytest.raises(ValueError):
        plan(cells, repeat=0)
    with pytest.raises(ValueError):
        expand((), (0,))


def test_impairment_and_command_of_a_run():
    assert impair_spec(Cell(20, 200, 0)) == "all/udp=after 2s delay 200ms loss 20%"
    assert impair_spec(Cell(5, 50, 10), "uplinks") == "uplinks=after 2s delay 50ms jitter 10ms loss 5%"
    assert impair_spec(Cell(0, 0, 0)) == "all/udp=after 2s"  # the baseline keeps its (clean) proxies
    run = plan([Cell(40, 0, 0, recovery=False)], 2, seed=7)[1]
    cmd = mission_command(run, "/tmp/x", speed=8, uavs=2, python="py")
    assert cmd[:4] == ["py", "-m", "services.cli", "mission"]
    assert cmd[cmd.index("--seed") + 1] == "8" and cmd[cmd.index("--speed") + 1] == "8"
    assert cmd[cmd.index("--impair") + 1] == "all/udp=after 2s loss 40%" and cmd[-1] == "--no-recovery"
    assert "--no-recovery" not in mission_command(plan([Cell(40, 0, 0)], 1)[0], "/tmp/x")
    assert check_links(" all/udp ", 3) == "all/udp" and check_links("uav1-uav3", 3) == "uav1-uav3"
    for bad in ("uav4", "everything", "all/sctp", "uav1-uav1"):
        with pytest.raises(ValueError, match="--links"):
            check_links(bad, 3)


REPORT = {
    "success": True,
    "captures": {"planned": 26, "imaged": 25, "ratio": 25 / 26},
    "links": {"command": {"sent": 15, "delivered": 15, "ratio": 1.0, "latency_ms": {"p50": 1.0, "p95": 3.0}},
              "telemetry": {"ratio": 0.9, "latency_ms": {"p50": 2.0, "p95": 250.0}},
              "imagery": {"latency_ms": {"p95": 600.0}}},
    "imagery": {"uav1.cam0": {"delivered": 13, "lost": 1, "late": 0, "recovered": 3, "jitter_ms": 50.0},
                "uav2.cam0": {"delivered": 12, "lost": 0, "late": 1, "recovered": 2, "jitter_ms": 70.0}},
    "formation": {"rms_m": 0.2, "max_m": 0.9},
    "defects": {"n_found": 18, "n_truth": 19, "recall": 18 / 19, "precision": 0.5},
}


def test_run_metrics_read_the_report():
    m = run_metrics(json.loads(json.dumps(REPORT)), wall_s=31.0)
    assert set(m) == set(METRICS)
    assert m["success"] == 1.0 and m["coverage"] == pytest.approx(25 / 26) and m["captures_planned"] == 26
    assert (m["cmd_ack_ratio"], m["cmd_ack_p95_ms"], m["cmd_failed"]) == (1.0, 3.0, 0.0)
    assert (m["telemetry_ratio"], m["telemetry_age_p95_ms"]) == (0.9, 250.0)
    assert (m["img_delivered"], m["img_lost"], m["img_late"], m["img_recovered"]) == (25, 1, 1, 5)
    assert m["img_missing"] == 0  # 26 planned: 25 delivered in order, 1 late (analysed all the same)
    assert m["img_jitter_ms"] == 70.0 and m["capture_to_report_p95_ms"] == 600.0
    assert (m["defects_found"], m["defects_planted"], m["formation_rms_m"], m["wall_s"]) == (18, 19, 0.2, 31.0)
    # nothing to read: failure, and no invented figures
    empty = run_metrics(None, 5.0)
    assert empty["success"] == 0.0 and empty["coverage"] is None and empty["wall_s"] == 5.0
    hung = run_metrics(REPORT, 300.0, hung=True)
    assert hung["success"] == 0.0 and hung["coverage"] == pytest.approx(25 / 26)
    odd = run_metrics({"success": "yes", "captures": {"ratio": float("nan")}, "imagery": {}})
    assert odd["success"] == 0.0 and odd["coverage"] is None and odd["img_lost"] is None
    assert odd["img_missing"] is None
    # a report of the wrong shape gives no figures rather than an error
    misshapen = run_metrics({"success": True, "links": {"command": [1, 2], "telemetry": "x"}, "imagery": [3]})
    assert misshapen["success"] == 1.0 and misshapen["cmd_ack_ratio"] is None and misshapen["cmd_failed"] is None
    assert misshapen["telemetry_ratio"] is None and misshapen["img_delivered"] is None
    assert run_metrics([1, 2], 3.0)["success"] == 0.0  # type: ignore[arg-type]


def test_aggregate_and_table():
    runs = [{"status": "ok", "metrics": run_metrics(REPORT, 30.0)},
            {"status": "ok", "metrics": {**run_metrics(REPORT, 40.0), "coverage": 1.0, "success": 0.0}},
            {"status": "hung", "metrics": run_metrics(None, 300.0, hung=True)}]
    a = aggregate(runs)
    assert (a["runs"], a["succeeded"], a["hung"], a["failed_to_report"]) == (3, 1, 1, 0)
    cov = a["metrics"]["coverage"]
    assert cov["n"] == 2 and cov["min"] == pytest.approx(25 / 26) and cov["max"] == 1.0
    assert a["metrics"]["success"]["mean"] == pytest.approx(1 / 3)
    assert a["metrics"]["wall_s"] == {"mean": pytest.approx(370 / 3), "min": 30.0, "max": 300.0, "n": 3}
    assert aggregate([])["metrics"]["coverage"] is None
    row = {"cell": Cell(20, 200, 0, False).as_dict(), **a}
    lines = markdown([row]).splitlines()
    assert len(lines) == 3 and lines[0].startswith("| loss % | delay ms")
    cells = [c.strip() for c in lines[2].strip("|").split("|")]
    assert cells[:5] == ["20", "200", "0", "off", "1/3"]
    assert cells[5] == "98 (96-100)" and cells[-1] == "1 hung" and cells[-2] == "18.0/19"
