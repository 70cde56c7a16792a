"""Tests for protocol.stages: per-stage duration samples, bounded, and their percentiles."""

from __future__ import annotations

import math

import pytest

from protocol.stages import StageTimes


def test_summary_in_milliseconds_in_first_seen_order():
    t = StageTimes()
    for s in (0.010, 0.020, 0.030, 0.040, 0.100):
        t.add("decode", s)
    t.add("arrival", -0.002)  # clocks of two machines: kept as measured
    assert t.stages == ["decode", "arrival"]
    d = t.summary()["decode"]
    assert d["n"] == 5 and d["p50"] == pytest.approx(30.0) and d["max"] == pytest.approx(100.0)
    assert 40.0 < d["p95"] < 100.0
    assert t.summary()["arrival"]["max"] == pytest.approx(-2.0)


def test_only_the_last_capacity_samples_are_kept():
    t = StageTimes(capacity=3)
    for s in (9.0, 9.0, 0.001, 0.002, 0.003):
        t.add("queue", s)
    q = t.summary()["queue"]
    assert q["n"] == 3 and q["max"] == pytest.approx(3.0)


def test_metrics_flatten_the_summary():
    t = StageTimes()
    t.add("worker", 0.05)
    m = t.metrics()
    assert m == {"path.worker.p50_ms": pytest.approx(50.0), "path.worker.p95_ms": pytest.approx(50.0),
                 "path.worker.max_ms": pytest.approx(50.0), "path.worker.n": 1}
    assert StageTimes().metrics() == {} and StageTimes().summary() == {}


@pytest.mark.parametrize("stage, seconds", [("", 1.0), (None, 1.0), ("x", math.nan), ("x", math.inf),
                                            ("x", "1"), ("x", True)])
def test_bad_samples_are_refused(stage, seconds):
    with pytest.raises(ValueError):
        StageTimes().add(stage, seconds)


@pytest.mark.parametrize("capacity", [0, -1, 1.5, True])
def test_bad_capacity(capacity):
    with pytest.raises(ValueError):
        StageTimes(capacity)
