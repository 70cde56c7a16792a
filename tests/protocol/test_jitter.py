"""Tests of protocol.jitter: reorder, loss, duplicates, late frames, wrap, resync, RFC 3550 jitter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.jitter import MAX_DROPOUT, Frame, JitterBuffer, JitterBuffers, JitterStats
from protocol.rtp import RtpHeader, RtpSender, seq_add, ssrc_for

SSRC = 0x534B0100


def h(seq: int, ts: int | None = None, ssrc: int = SSRC) -> RtpHeader:
    """Header of frame ``seq`` (may be given unwrapped) of a 30 fps stream: 3000 ticks apart at 90 kHz."""
    return RtpHeader(sequence=seq % 65536, timestamp=(3000 * seq if ts is None else ts) % 2**32, ssrc=ssrc)


def seqs(frames: list[Frame]) -> list[int]:
    return [f.sequence for f in frames]


# ------------------------------------------------------------------------------- ordering


def test_in_order_frames_are_released_at_once_across_the_wrap() -> None:
    jb = JitterBuffer(capacity=16, playout_delay_s=0.1)
    start = 65530
    for i in range(12):
        seq = (start + i) % 65536
        out = jb.push(h(start + i), b"img%d" % i, arrival_s=i / 30)
        assert seqs(out) == [seq]
        assert out[0].payload == b"img%d" % i and out[0].arrival_s == i / 30
        assert out[0].extended_sequence == start + i
    s = jb.stats()
    assert (s.received, s.delivered, s.lost, s.reordered, s.duplicated, s.late) == (12, 12, 0, 0, 0, 0)
    assert s.highest_sequence == start + 11 == 65541  # one wrap cycle: 65536 + 5
    assert s.expected == 12 and s.fraction_lost == 0.0 and s.cumulative_lost == 0
    assert s.buffered == 0 and jb.next_deadline() is None


def test_reorder_inside_the_window_is_delivered_in_order() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    assert seqs(jb.push(h(100), b"", 0.00)) == [100]
    assert jb.push(h(103), b"", 0.01) == []
    assert jb.push(h(102), b"", 0.02) == []
    assert len(jb) == 2 and jb.next_deadline() == pytest.approx(0.11)
    assert seqs(jb.push(h(101), b"", 0.03)) == [101, 102, 103]
    s = jb.stats()
    assert (s.reordered, s.lost, s.delivered, s.buffered) == (2, 0, 4, 0)
    assert s.highest_sequence == 103


def test_reorder_across_the_wrap() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    order = [65534, 0, 65535, 2, 1, 3]
    released = [f for i, q in enumerate(order) for f in jb.push(h(q), b"", i * 0.01)]
    assert seqs(released) == [65534, 65535, 0, 1, 2, 3]
    assert [f.extended_sequence for f in released] == list(range(65534, 65540))
    assert jb.stats().reordered == 2 and jb.stats().highest_sequence == 65539


# ------------------------------------------------------------------------------- loss


def test_gap_is_given_up_after_the_playout_delay() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    jb.push(h(10), b"", 0.000)
    assert jb.push(h(12), b"", 0.040) == []  # 11 missing: first known at 0.040
    assert jb.push(h(13), b"", 0.070) == []
    assert jb.next_deadline() == pytest.approx(0.140)
    assert jb.pop_due(0.139) == []
    assert seqs(jb.pop_due(0.140)) == [12, 13]
    s = jb.stats()
    assert (s.lost, s.delivered, s.expected) == (1, 3, 4)
    assert s.fraction_lost == pytest.approx(0.25)
    assert s.cumulative_lost == 1  # RFC 3550 A.3: expected - received


def test_a_push_also_releases_what_is_due_by_its_arrival() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.05)
    jb.push(h(1), b"", 0.0)
    jb.push(h(3), b"", 0.01)
    assert seqs(jb.push(h(4), b"", 0.2)) == [3, 4]  # 2 given up at 0.06, 4 then in order
    assert jb.stats().lost == 1


def test_later_gaps_wait_for_their_own_deadline() -> None:
    jb = JitterBuffer(capacity=16, playout_delay_s=0.125)  # binary-exact times below
    jb.push(h(0), b"", 0.0)
    jb.push(h(2), b"", 0.0625)  # 1 missing since 0.0625
    jb.push(h(5), b"", 0.125)  # 3 and 4 missing since 0.125
    assert jb.pop_due(0.125) == []
    assert seqs(jb.pop_due(0.1875)) == [2]
    assert jb.next_deadline() == 0.25
    assert jb.pop_due(0.2499) == []
    assert seqs(jb.pop_due(0.25)) == [5]
    assert jb.stats().lost == 3


def test_zero_delay_gives_gaps_up_immediately() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.0)
    jb.push(h(1), b"", 0.0)
    assert seqs(jb.push(h(3), b"", 0.1)) == [3]
    assert jb.push(h(2), b"", 0.2) == []
    assert (jb.stats().lost, jb.stats().late) == (1, 1)


def test_full_window_gives_up_the_oldest_gap() -> None:
    jb = JitterBuffer(capacity=4, playout_delay_s=10.0)
    jb.push(h(0), b"", 0.0)
    for q in (2, 3, 4):  # 1 is missing; window [1, 4] is now full
        assert jb.push(h(q), b"", 0.01 * q) == []
    assert seqs(jb.push(h(5), b"", 0.05)) == [2, 3, 4, 5]
    s = jb.stats()
    assert (s.lost, s.resyncs, s.delivered) == (1, 0, 5)


def test_flush_releases_everything_in_order() -> None:
    jb = JitterBuffer(capacity=16, playout_delay_s=5.0)
    jb.push(h(65535), b"", 0.0)
    for q in (3, 1, 5):
        jb.push(h(q), b"", 0.1)
    assert seqs(jb.flush()) == [1, 3, 5]
    s = jb.stats()
    assert (s.lost, s.buffered, s.delivered, s.expected) == (3, 0, 4, 7)  # 0, 2, 4 lost
    assert seqs(jb.push(h(6), b"", 0.2)) == [6]  # the stream goes on after a flush


# ------------------------------------------------------------------------------- duplicates, late


def test_duplicates_are_counted_and_dropped() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    jb.push(h(1), b"a", 0.0)
    assert jb.push(h(1), b"a", 0.01) == []  # of a played frame
    jb.push(h(3), b"c", 0.02)
    assert jb.push(h(3), b"c", 0.03) == []  # of a buffered frame
    out = jb.push(h(2), b"b", 0.04)
    assert seqs(out) == [2, 3] and [f.payload for f in out] == [b"b", b"c"]
    assert jb.push(h(2), b"b", 0.05) == []
    s = jb.stats()
    assert (s.duplicated, s.late, s.delivered, s.received) == (3, 0, 3, 6)
    assert s.cumulative_lost == -3  # RFC 3550 A.3: duplicates make it negative


def test_late_frame_after_its_gap_was_given_up() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    jb.push(h(1), b"", 0.0)
    jb.push(h(3), b"", 0.01)
    assert seqs(jb.pop_due(0.2)) == [3]
    assert jb.push(h(2), b"", 0.25) == []
    s = jb.stats()
    assert (s.late, s.duplicated, s.lost, s.delivered) == (1, 0, 1, 2)


def test_late_across_the_wrap() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.0)
    jb.push(h(65534), b"", 0.0)
    assert seqs(jb.push(h(1), b"", 0.1)) == [1]  # 65535 and 0 given up
    assert jb.push(h(65535), b"", 0.2) == []
    assert jb.push(h(0), b"", 0.3) == []
    assert jb.push(h(65534), b"", 0.4) == []
    s = jb.stats()
    assert (s.late, s.duplicated, s.lost, s.highest_sequence) == (2, 1, 2, 65537)


# ------------------------------------------------------------------------------- jumps


def test_resync_after_a_huge_jump_confirmed_by_the_next_packet() -> None:
    jb = JitterBuffer(capacity=64, playout_delay_s=0.1)
    for i, q in enumerate(range(65533, 65538)):  # 65533..1 across the wrap
        jb.push(h(q), b"", i * 0.03)
    jb.push(h(3), b"", 0.16)  # 2 missing: held
    assert jb.push(h(40000), b"new", 0.17) == []  # a jump: held as a probe, not yet trusted
    assert len(jb) == 2
    out = jb.push(h(40001), b"new", 0.20)
    assert seqs(out) == [3, 40000, 40001]
    s = jb.stats()
    assert s.resyncs == 1
    assert (s.delivered, s.lost) == (8, 1)  # the old window's gap (2) still counts; the jump not
    assert s.expected == 7 + 2  # two numbering epochs: 65533..3 and 40000..40001
    assert s.highest_sequence == 40001  # the new epoch restarts extended numbering (RFC 3550 A.1)
    assert seqs(jb.push(h(40002), b"", 0.23)) == [40002]


def test_a_lone_jumped_frame_resyncs_after_the_playout_delay() -> None:
    jb = JitterBuffer(capacity=16, playout_delay_s=0.1)
    jb.push(h(10), b"", 0.0)
    assert jb.push(h(30000), b"", 1.0) == []
    assert jb.next_deadline() == pytest.approx(1.1)
    assert jb.pop_due(1.05) == []
    assert seqs(jb.pop_due(1.1)) == [30000]
    assert jb.stats().resyncs == 1


def test_backward_jump_beyond_the_window_is_a_restart_not_late() -> None:
    jb = JitterBuffer(capacity=16, playout_delay_s=0.1)
    for q in range(5000, 5010):
        jb.push(h(q), b"", q * 0.001)
    jb.push(h(17), b"", 6.0)  # sender restarted with a lower initial sequence number
    assert seqs(jb.push(h(18), b"", 6.03)) == [17, 18]
    s = jb.stats()
    assert (s.resyncs, s.late, s.lost, s.expected) == (1, 0, 0, 12)


def test_outage_longer_than_the_window_counts_as_loss() -> None:
    jb = JitterBuffer(capacity=64, playout_delay_s=0.1)
    for q in range(65530, 65536):
        jb.push(h(q), b"", 0.0)
    jump = 1000  # > capacity, < MAX_DROPOUT
    assert jump < MAX_DROPOUT
    first = seq_add(65535, jump)
    jb.push(h(first), b"", 5.0)
    assert seqs(jb.push(h(first + 1), b"", 5.03)) == [first, first + 1]
    s = jb.stats()
    assert s.resyncs == 1 and s.lost == jump - 1
    assert s.highest_sequence == 65535 + jump + 1  # numbering continues across the outage
    assert s.expected == 6 + jump + 1 and s.delivered == 8


def test_a_stray_far_off_packet_does_not_resync() -> None:
    jb = JitterBuffer(capacity=16, playout_delay_s=0.1)
    jb.push(h(100), b"", 0.00)
    assert jb.push(h(9000), b"", 0.01) == []
    assert seqs(jb.push(h(101), b"", 0.02)) == [101]
    assert jb.pop_due(1.0) == []
    s = jb.stats()
    assert (s.resyncs, s.late, s.delivered, s.buffered) == (0, 1, 2, 0)


def test_duplicate_probe_is_a_duplicate() -> None:
    jb = JitterBuffer(capacity=16, playout_delay_s=0.1)
    jb.push(h(100), b"", 0.00)
    jb.push(h(9000), b"", 0.01)
    jb.push(h(9000), b"", 0.02)
    assert seqs(jb.push(h(9001), b"", 0.03)) == [9000, 9001]
    assert (jb.stats().duplicated, jb.stats().resyncs) == (1, 1)


# ------------------------------------------------------------------------------- jitter


def test_interarrival_jitter_against_a_hand_computation() -> None:
    """RFC 3550 A.8 by hand: 30 fps at 90 kHz, S_i = 3000 i; R_i = arrival * 90000."""
    arrivals = [0.000, 0.040, 0.070, 0.095, 0.140]  # R = 0, 3600, 6300, 8550, 12600 ticks
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1, clock_rate=90_000)
    # D(0,1) = (3600 - 0)    - (3000 - 0)    =  600  ->  J = 0      + (600 - 0)      / 16 = 37.5
    # D(1,2) = (6300 - 3600) - (6000 - 3000) = -300  ->  J = 37.5   + (300 - 37.5)   / 16 = 53.90625
    # D(2,3) = (8550 - 6300) - (9000 - 6000) = -750  ->  J = 53.90625 + (750 - 53.90625) / 16
    #                                                     = 97.412109375
    # D(3,4) = (12600 - 8550) - (12000 - 9000) = 1050 ->  J = 97.412109375 + (1050 - 97.412109375) / 16
    #                                                     = 156.9488525390625
    expected = [0.0, 37.5, 53.90625, 97.412109375, 156.9488525390625]
    for i, (t, want) in enumerate(zip(arrivals, expected)):
        jb.push(h(i), b"", t)
        assert jb.stats().jitter_ts == pytest.approx(want, rel=1e-9, abs=1e-6)
    assert jb.stats().jitter_s == pytest.approx(156.9488525390625 / 90_000, rel=1e-9)


def test_jitter_is_unchanged_by_timestamp_and_sequence_wrap() -> None:
    arrivals = [0.000, 0.040, 0.070, 0.095, 0.140]
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    base_ts = 2**32 - 6000  # the timestamps wrap between the 2nd and 3rd frames
    for i, t in enumerate(arrivals):
        jb.push(h(65534 + i, ts=base_ts + 3000 * i), b"", t)
    assert jb.stats().jitter_ts == pytest.approx(156.9488525390625, rel=1e-9)


def test_jitter_of_a_perfectly_paced_stream_is_zero_and_reorder_counts() -> None:
    jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    for i in range(20):
        jb.push(h(i), b"", 5.0 + i / 30)
    assert jb.stats().jitter_ts == pytest.approx(0.0, abs=1e-6)
    # a swapped pair, each frame arriving in the other's time slot, by hand:
    # frame 21 arrives in slot 20's time: D = (1/30 s = 3000 ticks) - (21 - 19) * 3000 = -3000
    jb2 = JitterBuffer(capacity=8, playout_delay_s=0.1)
    jb2.push(h(19), b"", 0.0)
    jb2.push(h(21), b"", 1 / 30)
    assert jb2.stats().jitter_ts == pytest.approx(3000 / 16, rel=1e-9)
    # frame 20 then arrives at slot 21's time: D = 3000 - (20 - 21) * 3000 = 6000
    jb2.push(h(20), b"", 2 / 30)
    assert jb2.stats().jitter_ts == pytest.approx(3000 / 16 + (6000 - 3000 / 16) / 16, rel=1e-9)


# ------------------------------------------------------------------------------- validation


@pytest.mark.parametrize("kwargs", [
    {"capacity": 0}, {"capacity": 1 << 15}, {"capacity": 4.0}, {"playout_delay_s": -0.1},
    {"playout_delay_s": math.nan}, {"clock_rate": 0}, {"clock_rate": 9e4},
])
def test_bad_parameters(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        JitterBuffer(**kwargs)


def test_bad_input_is_a_value_error() -> None:
    jb = JitterBuffer()
    jb.push(h(1), b"", 0.0)
    with pytest.raises(ValueError, match="SSRC"):
        jb.push(h(2, ssrc=99), b"", 0.1)
    for bad_t in (math.nan, math.inf, "soon", None):
        with pytest.raises(ValueError):
            jb.push(h(2), b"", bad_t)
    with pytest.raises(ValueError):
        jb.pop_due(math.nan)
    with pytest.raises(ValueError):
        jb.push((2, 0, SSRC), b"", 0.1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="payload"):
        jb.push(h(2), None, 0.1)  # type: ignore[arg-type]
    assert jb.stats().received == 1  # refused packets are not counted


# ------------------------------------------------------------------------------- several sources


def test_buffers_keyed_per_ssrc() -> None:
    cams = JitterBuffers(capacity=8, playout_delay_s=0.1, max_sources=2)
    a, b = RtpSender(ssrc_for(1), initial_seq=65535), RtpSender(ssrc_for(2), initial_seq=7)
    pa = [a.frame(b"a%d" % i, i / 10) for i in range(3)]
    pb = [b.frame(b"b%d" % i, i / 10) for i in range(3)]
    out = []
    for packet, t in [(pa[0], 0.0), (pb[0], 0.0), (pb[2], 0.01), (pa[2], 0.02), (pa[1], 0.03)]:
        out += cams.push_packet(packet, t)
    assert [(f.ssrc, f.sequence) for f in out] == [
        (ssrc_for(1), 65535), (ssrc_for(2), 7), (ssrc_for(1), 0), (ssrc_for(1), 1)]
    assert [bytes(f.payload) for f in out] == [b"a0", b"b0", b"a1", b"a2"]
    assert cams.next_deadline() == pytest.approx(0.11)
    assert [f.sequence for f in cams.pop_due(0.2)] == [9]
    stats = cams.stats()
    assert set(stats) == {ssrc_for(1), ssrc_for(2)} and len(cams) == 2
    assert isinstance(stats[ssrc_for(2)], JitterStats)
    assert (stats[ssrc_for(1)].reordered, stats[ssrc_for(2)].lost) == (1, 1)
    with pytest.raises(ValueError, match="max_sources"):
        cams.push(h(1, ssrc=ssrc_for(3)), b"", 0.3)
    assert cams.remove(ssrc_for(2)) == [] and ssrc_for(2) not in cams
    cams.push(h(1, ssrc=ssrc_for(3)), b"", 0.3)
    assert sorted(cams.sources) == [ssrc_for(1), ssrc_for(3)]
    assert stats[ssrc_for(1)].as_dict()["delivered"] == 3


def test_buffers_flush_and_bad_packet() -> None:
    cams = JitterBuffers(playout_delay_s=1.0)
    cams.push(h(1), b"", 0.0)
    cams.push(h(3), b"", 0.1)
    assert [f.sequence for f in cams.flush()] == [3]
    with pytest.raises(ValueError):  # RtpError is a ValueError
        cams.push_packet(b"\x80\x1a", 0.2)
    with pytest.raises(ValueError):
        cams.push(h(1, ssrc=5), b"", math.nan)
    assert 5 not in cams  # a refused packet creates no buffer


# ------------------------------------------------------------------------------- properties


@settings(max_examples=120, deadline=None)
@given(
    start=st.integers(65000, 65535),
    n=st.integers(1, 120),
    seed=st.integers(0, 2**32 - 1),
    drop=st.floats(0.0, 0.3),
    dup=st.floats(0.0, 0.2),
    spread=st.integers(0, 6),
)
def test_impaired_stream_invariants(start: int, n: int, seed: int, drop: float, dup: float, spread: int) -> None:
    """Loss, duplication and bounded reordering (< capacity) near the wrap: accounting balances."""
    rng = np.random.default_rng(seed)
    ext = start + np.arange(n)
    send_t = np.arange(n) / 30
    keep = rng.random(n) >= drop
    keep[0] = True  # the first packet anchors the stream
    ext, send_t = ext[keep], send_t[keep]
    twice = rng.random(ext.size) < dup
    copies = np.concatenate([ext, ext[twice]])
    arrive = np.concatenate([send_t, send_t[twice]])
    arrive = arrive + rng.integers(0, spread + 1, size=copies.size) / 30
    arrive[0] = -1.0
    order = np.argsort(arrive, kind="stable")
    jb = JitterBuffer(capacity=32, playout_delay_s=0.1)
    out: list[Frame] = []
    for k in order:
        out += jb.push(h(int(copies[k])), b"", float(arrive[k]))
    out += jb.flush()
    got = [f.extended_sequence for f in out]
    assert got == sorted(set(got))  # strictly increasing: in order, never twice
    assert set(got) <= set(ext.tolist())
    s = jb.stats()
    assert s.resyncs == 0
    assert s.received == copies.size == s.delivered + s.duplicated + s.late
    assert s.highest_sequence == ext.max()
    assert s.delivered + s.lost == s.expected == ext.max() - start + 1
    assert s.buffered == 0 and s.jitter_ts >= 0


def test_release_late_hands_a_given_up_frame_out_after_the_ones_in_order():
    from protocol.rtp import RtpHeader

    for release in (False, True):
        jb = JitterBuffer(capacity=8, playout_delay_s=0.0, release_late=release)
        jb.push(RtpHeader(0, 0, 7), b"a", 0.0)
        assert [f.sequence for f in jb.push(RtpHeader(2, 6000, 7), b"c", 0.1)] == [2]  # 1 given up at once
        late = jb.push(RtpHeader(1, 3000, 7), b"b", 0.2)
        assert jb.late == 1 and jb.late_released == int(release)
        assert [(f.sequence, bytes(f.payload)) for f in late] == ([(1, b"b")] if release else [])
