"""Tests of services.netem.model: parsing, validation and the seeded per-packet decisions (pure)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.netem.model import GilbertElliott, Impairer, Impairment


# ------------------------------------------------------------------------------ parsing
def test_parse_the_netem_like_string():
    imp = Impairment.parse("delay 50ms jitter 10ms loss 2% duplicate 1% reorder 5% rate 2mbit")
    assert (imp.delay_ms, imp.jitter_ms, imp.loss, imp.duplicate, imp.reorder) == (50.0, 10.0, 0.02, 0.01, 0.05)
    assert imp.rate_kbps == 2000.0
    assert imp.fifo and imp.limit == 1000 and imp.distribution == "uniform"


def test_parse_netem_forms_and_units():
    imp = Impairment.parse("delay 1s 500us loss random 3% 25% reorder 10% 20ms limit 50 rto 300ms unordered "
                           "distribution normal outage 5s 2s outage 1s 250ms")
    assert imp.delay_ms == 1000.0 and imp.jitter_ms == pytest.approx(0.5)
    assert imp.loss == 0.03 and imp.loss_correlation == 0.25
    assert imp.reorder_ms == 20.0 and imp.limit == 50 and imp.rto_ms == 300.0
    assert not imp.fifo and imp.distribution == "normal"
    assert imp.outages == ((1.0, 0.25), (5.0, 2.0))  # sorted by start


@pytest.mark.parametrize("text, kbps", [("2mbit", 2000.0), ("500kbit", 500.0), ("100kbps", 800.0),
                                        ("1MBps", 8000.0), ("64000", 64.0), ("1kibit", 1.024)])
def test_rates_use_tc_units_where_bps_means_bytes(text, kbps):
    assert Impairment.parse(f"rate {text}").rate_kbps == pytest.approx(kbps)


def test_gemodel_defaults_follow_netem():
    g = Impairment.parse("loss gemodel 1%").gilbert_elliott
    assert (g.p, g.r, g.loss_bad, g.loss_good) == (0.01, 0.99, 1.0, 0.0)  # one parameter: Bernoulli-like
    g = Impairment.parse("loss gemodel 1% 30% 80% 0.1%").gilbert_elliott
    assert (g.p, g.r, g.loss_bad, g.loss_good) == (0.01, 0.30, 0.80, 0.001)
    assert g.mean_loss == pytest.approx((0.01 * 0.8 + 0.3 * 0.001) / 0.31)


def test_empty_and_none_are_the_null_impairment():
    assert Impairment.parse("").is_null and Impairment.parse("none").is_null
    assert not Impairment.parse("outage 1s 1s").is_null
    assert Impairment.coerce(None) == Impairment()


@pytest.mark.parametrize("text, token", [
    ("delay 50", "'50'"), ("delay 50ms loss 2", "'2'"), ("loss 150%", "'150%'"),
    ("delay 5ms frobnicate 3", "'frobnicate'"), ("delay", "'delay'"), ("rate 2mbbit", "'2mbbit'"),
    ("outage 1s", "'outage'"), ("distribution pareto", "'pareto'"), ("limit 1.5", "'1.5'"),
    ("delay 10parsecs", "'10parsecs'"), ("duplicate 1% 25%", "'25%'"),
])
def test_parse_errors_name_the_bad_token(text, token):
    with pytest.raises(ValueError) as e:
        Impairment.parse(text)
    assert token in str(e.value)


@pytest.mark.parametrize("data", [
    {"delay_ms": float("nan")}, {"delay_ms": -1.0}, {"jitter_ms": float("inf")}, {"loss": 1.5},
    {"duplicate": -0.1}, {"rate_kbps": -5}, {"outages": [(1.0, 0.0)]}, {"outages": [(-1.0, 1.0)]},
    {"outages": [(float("nan"), 1.0)]}, {"loss": 0.1, "gilbert_elliott": {"p": 0.1, "r": 0.5}},
    {"gilbert_elliott": {"p": 0.0, "r": 0.0}}, {"delays_ms": 5}, {"loss_correlation": 1.0},
])
def test_bad_dicts_are_value_errors(data):
    with pytest.raises(ValueError):
        Impairment.from_dict(data)


def test_from_dict_and_coerce():
    imp = Impairment.from_dict({"delay_ms": 20, "loss": 0.01, "outages": [[2, 1]]})
    assert imp.outages == ((2.0, 1.0),) and imp.delay_ms == 20.0
    assert Impairment.coerce("delay 20ms loss 1% outage 2s 1s") == imp
    with pytest.raises(ValueError):
        Impairment.coerce(42)
    with pytest.raises(ValueError):
        Impairment.from_dict("delay 5ms")


pct = st.floats(0.0, 1.0, allow_nan=False)
ms = st.floats(0.0, 5000.0, allow_nan=False)


@given(delay=ms, jitter=ms, loss=pct, dup=pct, reorder=pct, rate=st.floats(0.0, 1e6, allow_nan=False),
       fifo=st.booleans(), outages=st.lists(st.tuples(st.floats(0, 100), st.floats(0.001, 10)), max_size=3))
@settings(max_examples=60, deadline=None)
def test_to_text_parses_back(delay, jitter, loss, dup, reorder, rate, fifo, outages):
    imp = Impairment(delay_ms=delay, jitter_ms=jitter, loss=loss, duplicate=dup, reorder=reorder,
                     rate_kbps=rate, fifo=fifo, outages=tuple(outages))
    back = Impairment.parse(imp.to_text())
    for name in ("delay_ms", "jitter_ms", "loss", "duplicate", "reorder", "rate_kbps"):
        assert getattr(back, name) == pytest.approx(getattr(imp, name), rel=1e-12, abs=1e-15)
    assert back.fifo == imp.fifo and len(back.outages) == len(imp.outages)


# ------------------------------------------------------------------------------ decisions
def test_impairer_rejects_bad_input():
    imp = Impairer("delay 5ms", rng=1)
    for now, size in [(float("nan"), 10), (math.inf, 10), (0.0, -1), (0.0, 1.5), ("0", 10)]:
        with pytest.raises(ValueError):
            imp.decide(now, size)
        with pytest.raises(ValueError):
            imp.decide_stream(now, size)
    with pytest.raises(ValueError):
        Impairer(None, origin_s=math.nan)


def test_null_impairment_releases_at_once():
    imp = Impairer(None, rng=0)
    assert [imp.decide(t, 100) for t in (1.0, 2.0)] == [[1.0], [2.0]]
    assert imp.decide_stream(3.0, 100) == 3.0
    assert imp.stats()["packets_out"] == 3 and imp.stats()["bytes_in"] == 300


def test_loss_rate_over_2000_packets_is_within_binomial_bounds():
    p, n = 0.1, 2000
    imp = Impairer("loss 10%", rng=42)
    kept = sum(bool(imp.decide(i * 1e-3, 100)) for i in range(n))
    lost = n - kept
    sigma = math.sqrt(n * p * (1 - p))
    assert abs(lost - n * p) < 4 * sigma
    assert imp.counters.dropped["loss"] == lost and imp.counters.packets_out == kept


def test_same_seed_same_decisions_other_seed_other_decisions():
    def run(seed):
        imp = Impairer("delay 10ms jitter 5ms loss 20% duplicate 10%", rng=seed)
        return [tuple(imp.decide(i * 1e-3, 200)) for i in range(500)]
    assert run(7) == run(7)
    assert run(7) != run(8)


def _bursts(lost: np.ndarray) -> np.ndarray:
    edges = np.diff(np.concatenate([[0], lost.astype(int), [0]]))
    return np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)


def test_correlated_loss_keeps_the_mean_and_lengthens_bursts():
    p, rho, n = 0.05, 0.6, 40000
    imp = Impairer("loss 5% 60%", rng=3)
    lost = np.array([not imp.decide(i * 1e-4, 10) for i in range(n)])
    sigma = math.sqrt(p * (1 - p) / n) * math.sqrt((1 + rho) / (1 - rho))  # AR(1)-inflated
    assert abs(lost.mean() - p) < 5 * sigma
    assert _bursts(lost).mean() == pytest.approx(1 / ((1 - rho) * (1 - p)), rel=0.15)
    bern = Impairer("loss 5%", rng=3)
    lost_b = np.array([not bern.decide(i * 1e-4, 10) for i in range(n)])
    assert _bursts(lost_b).mean() < 1.2 < _bursts(lost).mean()


def test_gilbert_elliott_loss_matches_its_stationary_rate():
    ge = GilbertElliott(p=0.02, r=0.25, loss_bad=0.9)
    imp = Impairer(Impairment(gilbert_elliott=ge), rng=5)
    lost = np.array([not imp.decide(i * 1e-4, 10) for i in range(40000)])
    assert lost.mean() == pytest.approx(ge.mean_loss, rel=0.15)
    assert _bursts(lost).mean() > 2.0  # bad state lasts 1/r = 4 packets


def test_duplicate_gives_two_copies_at_the_configured_rate():
    imp = Impairer("delay 5ms duplicate 20%", rng=11)
    out = [imp.decide(i * 1e-3, 100) for i in range(2000)]
    twos = sum(len(o) == 2 for o in out)
    assert abs(twos - 400) < 4 * math.sqrt(2000 * 0.2 * 0.8)
    assert imp.counters.duplicated == twos and imp.counters.packets_out == 2000 + twos
    assert all(t >= i * 1e-3 + 5e-3 - 1e-12 for i, o in enumerate(out) for t in o)


@pytest.mark.parametrize("distribution, sd_per_jitter", [("uniform", 1 / 3 ** 0.5), ("normal", 1.0)])
def test_delay_and_jitter_statistics(distribution, sd_per_jitter):
    imp = Impairer(f"delay 50ms jitter 10ms distribution {distribution} unordered", rng=4)
    d = np.array([imp.decide(float(i), 1)[0] - i for i in range(20000)])
    sd = 0.010 * sd_per_jitter
    assert abs(d.mean() - 0.050) < 4 * sd / len(d) ** 0.5
    assert d.std() == pytest.approx(sd, rel=0.03)
    if distribution == "uniform":
        assert 0.040 <= d.min() < 0.0401 and 0.0599 < d.max() <= 0.060


def test_fifo_jitter_never_reorders_but_unordered_does():
    def releases(text):
        imp = Impairer(text, rng=2)
        return np.array([imp.decide(i * 1e-3, 100)[0] for i in range(1000)])
    fifo = releases("delay 50ms jitter 20ms")
    assert np.all(np.diff(fifo) >= 0)
    assert np.median(fifo - np.arange(1000) * 1e-3) >= 0.05  # FIFO waits never shorten the delay
    tfifo = releases("delay 50ms jitter 20ms unordered")
    assert np.sum(np.diff(tfifo) < 0) > 100
    assert np.median(tfifo - np.arange(1000) * 1e-3) == pytest.approx(0.05, abs=0.003)


def test_reorder_holds_packets_back_so_later_ones_overtake():
    imp = Impairer("reorder 10% 5ms", rng=4)
    t = [imp.decide(i * 1e-3, 100)[0] for i in range(2000)]
    order = np.argsort(t, kind="stable")
    overtaken = np.sum(np.diff(order) < 0)
    assert imp.counters.reordered == pytest.approx(200, abs=4 * math.sqrt(2000 * 0.09))
    assert overtaken >= 0.8 * imp.counters.reordered


def test_rate_serialises_packets_one_after_another():
    imp = Impairer("rate 100kbit delay 10ms", rng=0)
    t = np.array([imp.decide(0.0, 1250)[0] for _ in range(10)])  # 1250 B = 0.1 s at 100 kbit/s
    assert np.allclose(t, 0.01 + 0.1 * np.arange(1, 11))
    assert imp.decide(5.0, 1250) == [pytest.approx(5.11)]  # idle link: no queue


def test_limit_drops_what_the_queue_cannot_hold():
    imp = Impairer("rate 100kbit limit 5", rng=0)
    kept = [bool(imp.decide(0.0, 1250)) for _ in range(8)]
    assert kept == [True] * 5 + [False] * 3 and imp.counters.dropped["queue"] == 3
    assert imp.decide(0.25, 1250)  # two have left the queue by then


def test_outage_drops_datagrams_and_stalls_streams():
    imp = Impairer("outage 1s 500ms outage 1500ms 200ms delay 10ms", rng=0, origin_s=100.0)
    assert imp.decide(100.9, 10) == [pytest.approx(100.91)]
    assert imp.decide(101.0, 10) == [] and imp.decide(101.69, 10) == []
    assert imp.decide(101.7, 10) == [pytest.approx(101.71)]
    assert imp.counters.dropped["outage"] == 2
    s = Impairer("outage 1s 500ms outage 1500ms 200ms delay 10ms", rng=0, origin_s=100.0)
    assert s.decide_stream(101.2, 10) == pytest.approx(101.71)  # chained windows: waits for both
    assert s.decide_stream(100.995, 10) == pytest.approx(101.71)  # would be released inside one
    assert s.counters.stalled == 2 and s.counters.dropped["outage"] == 0


def test_onset_leaves_the_link_clean_until_after_s():
    imp = Impairer("after 2s loss 100% outage 1s 500ms", rng=0, origin_s=10.0)
    assert imp.decide(11.9, 10) == [11.9] and imp.decide(12.0, 10) == []
    assert imp.decide(11.2, 10) == []  # outages keep their own times
    assert imp.counters.dropped == {"loss": 1, "outage": 1, "queue": 0}
    s = Impairer("after 2s delay 50ms", rng=0, origin_s=10.0)
    assert s.decide_stream(11.0, 10) == 11.0 and s.decide_stream(12.0, 10) == pytest.approx(12.05)
    assert Impairment.parse("after 1500ms").after_s == 1.5


def test_stream_loss_is_retransmission_delay_and_order_is_kept():
    imp = Impairer("loss 30% delay 5ms jitter 4ms rto 200ms", rng=9)
    t = np.array([imp.decide_stream(i * 1e-3, 1448) for i in range(500)])
    assert np.all(np.diff(t) >= 0)
    assert imp.counters.packets_out == 500 and sum(imp.counters.dropped.values()) == 0
    assert imp.counters.retransmitted == pytest.approx(150, abs=4 * math.sqrt(500 * 0.21))
    big = Impairer("loss 1%", rng=1)  # a 64 KB chunk is 46 segments: 1 - 0.99**46 = 37 % hit
    hits = sum(big.decide_stream(i * 10.0, 65536) > i * 10.0 for i in range(1000))
    assert hits == pytest.approx(370, abs=4 * math.sqrt(1000 * 0.37 * 0.63))


# ------------------------------------------------------------------------------ live changes
def test_update_applies_from_the_next_decision_keeping_counters_and_origin():
    imp = Impairer("delay 100ms", rng=1, origin_s=50.0)
    assert imp.decide(50.0, 10) == [pytest.approx(50.1)]
    assert imp.update("loss 100% outage 10s 1s") == Impairment.parse("loss 100% outage 10s 1s")
    assert imp.impairment.loss == 1.0 and imp.changes == 1
    assert imp.decide(50.2, 10) == [] and imp.counters.dropped["loss"] == 1
    imp.update("outage 10s 1s")  # windows count from the same origin: 60 s .. 61 s
    assert imp.decide(60.5, 10) == [] and imp.counters.dropped["outage"] == 1
    assert imp.decide(61.0, 10) == [61.0]
    assert imp.counters.packets_in == 4 and imp.counters.packets_out == 2  # counters carried over


def test_update_keeps_the_fifo_floor_so_decided_packets_keep_their_times():
    fifo, unordered = Impairer("delay 200ms", rng=0), Impairer("delay 200ms unordered", rng=0)
    assert fifo.decide(0.0, 1) == unordered.decide(0.0, 1) == [pytest.approx(0.2)]
    fifo.update(None)
    unordered.update("unordered")
    assert fifo.decide(0.01, 1) == [pytest.approx(0.2)]  # behind the packet still in flight
    assert unordered.decide(0.01, 1) == [0.01]
    assert fifo.decide_stream(0.3, 100) == 0.3


def test_update_keeps_the_random_stream_and_is_deterministic():
    def run(seed: int) -> list[int]:
        imp = Impairer("loss 50%", rng=seed)
        out = [len(imp.decide(i * 0.001, 10)) for i in range(300)]
        imp.update("loss 20% duplicate 10%")
        return out + [len(imp.decide(1.0 + i * 0.001, 10)) for i in range(300)]
    a, b = run(3), run(3)
    assert a == b and a != run(4)
    assert 0.35 < a[:300].count(0) / 300 < 0.65 and 0.1 < a[300:].count(0) / 300 < 0.3
    assert 2 in a[300:]  # the duplicate of the new impairment


def test_bad_update_changes_nothing():
    imp = Impairer("delay 5ms", rng=0)
    for bad in ("loss 2", {"delay_ms": -1}, 42):
        with pytest.raises(ValueError):
            imp.update(bad)
    assert imp.impairment == Impairment.parse("delay 5ms") and imp.changes == 0
    for now, duration in ((math.nan, 1.0), (0.0, 0.0), (0.0, -1.0), (0.0, math.inf)):
        with pytest.raises(ValueError):
            imp.cut(now, duration)
    assert imp.outage_end(0.0) is None


def test_cut_drops_datagrams_until_it_ends_or_is_restored():
    imp = Impairer("delay 10ms", rng=0, origin_s=100.0)
    imp.cut(101.0, 2.0)
    assert imp.decide(100.5, 1) != [] and imp.decide(101.0, 1) == [] and imp.decide(102.9, 1) == []
    assert imp.decide(103.0, 1) != [] and imp.counters.dropped["outage"] == 2
    imp.cut(104.0)  # until restore
    assert imp.outage_end(104.0) == math.inf == imp.cut_end(1e9)
    imp.update("delay 20ms")  # an update does not end the cut
    assert imp.decide(200.0, 1) == []
    imp.restore()
    assert imp.outage_end(200.0) is None and imp.decide(200.0, 1) == [pytest.approx(200.02)]
    assert imp.changes == 4


def test_cut_is_left_to_the_stream_sender_but_outage_windows_stall_streams():
    imp = Impairer("outage 1s 1s", rng=0, origin_s=0.0)
    imp.cut(5.0)
    assert imp.decide_stream(1.5, 100) == 2.0  # an outage window stalls the chunk to its end
    assert imp.decide_stream(5.5, 100) == 5.5  # a cut does not: the sender holds bytes meanwhile
    assert imp.outage_end(1.5) == 2.0 and imp.cut_end(1.5) is None
    assert imp.outage_end(5.5) == imp.cut_end(5.5) == math.inf
    assert imp.counters.stalled == 1


def test_changes_from_another_thread_while_deciding():
    import threading

    imp = Impairer("loss 10%", rng=0)
    stop = threading.Event()

    def flip() -> None:
        k = 0
        while not stop.is_set():
            imp.update("loss 10%" if k % 2 else "delay 1ms loss 30%")
            imp.cut(k * 1e-3, 1e-4) if k % 7 == 0 else imp.restore()
            k += 1

    t = threading.Thread(target=flip)
    t.start()
    try:
        for i in range(20000):
            imp.decide(i * 1e-4, 10)
            imp.decide_stream(i * 1e-4, 100)
    finally:
        stop.set()
        t.join()
    c = imp.counters
    assert c.packets_in == 40000 and imp.changes > 0
    assert c.packets_out + sum(c.dropped.values()) - c.duplicated == 40000
