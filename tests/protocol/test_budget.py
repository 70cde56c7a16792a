"""protocol.budget: per-source token buckets and size caps."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.budget import LIMITS, MAX_SOURCES, OTHER, Budget, Limit, TokenBucket, for_topic


def test_a_source_within_its_rate_is_never_dropped_and_a_flood_is_cut_to_the_rate():
    b = Budget(Limit(rate_hz=20.0, burst=20, max_bytes=1000))
    # the good source: 20 Hz for 10 s
    assert all(b.admit("uav/1/state", 500, t / 20) is None for t in range(200))
    # a flooding source: 10,000 samples in 1 s -> its burst plus 1 s of its rate
    flood = [b.admit("uav/2/state", 500, t / 10_000) for t in range(10_000)]
    assert flood.count(None) == 20 + 19  # its burst, then 20 / s over 0.9999 s
    assert b.dropped[("uav/2/state", "budget-rate")] == flood.count("budget-rate")
    assert not any(src == "uav/1/state" for src, _ in b.dropped)


def test_oversized_samples_are_dropped_whatever_the_rate():
    b = for_topic("event")
    assert b.admit("uav/1/event", LIMITS["event"].max_bytes + 1, 0.0) == "budget-size"
    assert b.admit("uav/1/event", 100, 0.0) is None


def test_made_up_sources_share_one_bucket_beyond_the_cap():
    b = Budget(Limit(1.0, 1, 10), max_sources=8)
    for i in range(1000):
        b.admit(f"uav/x{i}/event", 1, 0.0)
    assert b.sources() == 9  # 8 own buckets + (other)
    assert b.dropped[(OTHER, "budget-rate")] == 1000 - 8 - 1


def test_limits_are_valid_and_bad_ones_refused():
    assert MAX_SOURCES >= 255
    for lim in LIMITS.values():
        assert lim.rate_hz > 0 and lim.burst >= 1
    for bad in [(0, 1, 1), (float("nan"), 1, 1), (1, 0, 1), (1, 1, 0), (float("inf"), 1, 1)]:
        with pytest.raises(ValueError):
            Limit(*bad)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.1, 1000), st.integers(1, 100), st.lists(st.floats(0, 1e6, allow_nan=False), max_size=300))
def test_bucket_never_admits_more_than_burst_plus_rate_times_time(rate, burst, times):
    """Property: over any arrival times (even out of order), admitted <= burst + rate * elapsed."""
    b = TokenBucket(rate, float(burst))
    admitted = sum(b.take(t) for t in times)
    if times:
        elapsed = max(times) - times[0]
        assert admitted <= burst + rate * max(elapsed, 0.0) + 1e-6


def test_size_and_rate_checks_apart():
    """The bus checks the size before decoding and charges the rate only to well-formed samples."""
    b = Budget(Limit(1.0, 2, 100))
    assert b.admit_size("k", 101) == "budget-size" and b.admit_size("k", 100) is None
    assert [b.admit_rate("k", 0.0) for _ in range(3)] == [None, None, "budget-rate"]


def test_a_source_flooding_garbage_is_dropped_before_decoding_and_others_are_not():
    """Garbage takes from the source's own garbage bucket; once empty, that source is dropped undecoded
    (budget-garbage) until the bucket refills at the rate; a clean source is never touched."""
    b = Budget(Limit(rate_hz=10.0, burst=5, max_bytes=100))
    decoded = 0
    for i in range(10_000):  # 10,000 undecodable samples in 1 s
        now = i / 10_000
        if b.admit_undecoded("uav/1/state", 50, now) is None:
            decoded += 1
            b.charge_garbage("uav/1/state", now)
    assert decoded <= 5 + 10 * 1.0 + 1  # its burst plus 1 s of its rate
    assert b.dropped[("uav/1/state", "budget-garbage")] == 10_000 - decoded
    assert all(b.admit_undecoded("uav/2/state", 50, 1.0 + t / 20) is None for t in range(100))
    assert b.admit_undecoded("uav/2/state", 101, 2.0) == "budget-size"
    # after a quiet second the flooding source's bucket has refilled: it is decoded again
    assert b.admit_undecoded("uav/1/state", 50, 2.5) is None


def test_a_source_over_its_rate_is_dropped_before_decoding():
    """Once well-formed samples used up a source's rate, the next ones are refused undecoded (the same
    answer admit_rate would give after decoding), and it is admitted again as its bucket refills."""
    b = Budget(Limit(rate_hz=10.0, burst=3, max_bytes=100))
    assert [b.admit_undecoded("k", 10, 0.0) is None and b.admit_rate("k", 0.0) for _ in range(3)] == [None] * 3
    assert b.admit_undecoded("k", 10, 0.0) == "budget-rate"
    assert b.admit_undecoded("k", 10, 0.1) is None and b.admit_rate("k", 0.1) is None
    assert b.dropped[("k", "budget-rate")] == 1 and b.admit_undecoded("other", 10, 0.1) is None
