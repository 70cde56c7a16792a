"""Tests of protocol.rtp: RFC 3550 fixed header, 16-bit arithmetic, media clock, sender."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.rtp import (
    JPEG_PAYLOAD_TYPE,
    SKYNET_ENCODING_NAME,
    SKYNET_PAYLOAD_TYPE,
    RtpError,
    RtpHeader,
    RtpSender,
    media_timestamp,
    pack_frame,
    parse_ssrc,
    seq_add,
    seq_diff,
    seq_gt,
    seq_lt,
    ssrc_for,
    ts_add,
    ts_diff,
    unpack_frame,
    unwrap_sequence,
)


def rfc3550_parse(data: bytes) -> dict:
    """An independent reading of RFC 3550 section 5.1, bit by bit (not protocol.rtp)."""
    assert len(data) >= 12
    first, second = data[0], data[1]
    cc = first & 0b0000_1111
    out = {
        "version": (first & 0b1100_0000) >> 6,
        "padding": (first & 0b0010_0000) != 0,
        "extension": (first & 0b0001_0000) != 0,
        "csrc_count": cc,
        "marker": (second & 0b1000_0000) != 0,
        "payload_type": second & 0b0111_1111,
        "sequence": (data[2] << 8) | data[3],
        "timestamp": (data[4] << 24) | (data[5] << 16) | (data[6] << 8) | data[7],
        "ssrc": (data[8] << 24) | (data[9] << 16) | (data[10] << 8) | data[11],
    }
    offset = 12 + 4 * cc
    if out["extension"]:
        words = (data[offset + 2] << 8) | data[offset + 3]
        offset += 4 + 4 * words
    end = len(data)
    if out["padding"]:
        end -= data[-1]
    out["payload"] = bytes(data[offset:end])
    return out


EXTREMES = [
    RtpHeader(sequence=0, timestamp=0, ssrc=0, marker=False, payload_type=0),
    RtpHeader(sequence=65535, timestamp=2**32 - 1, ssrc=2**32 - 1, marker=True, payload_type=127),
    RtpHeader(sequence=1, timestamp=1, ssrc=1, marker=True, payload_type=JPEG_PAYLOAD_TYPE),
    RtpHeader(sequence=0x8000, timestamp=0x80000000, ssrc=0x534B0100, marker=False, payload_type=96),
]


# ------------------------------------------------------------------------------- header


@pytest.mark.parametrize("header", EXTREMES, ids=lambda h: f"seq{h.sequence}-m{int(h.marker)}-pt{h.payload_type}")
@pytest.mark.parametrize("payload", [b"", b"\xff\xd8jpeg\xff\xd9", bytes(range(256)) * 40])
def test_round_trip_every_field(header: RtpHeader, payload: bytes) -> None:
    packet = pack_frame(header, payload)
    assert len(packet) == 12 + len(payload)
    got, body = unpack_frame(packet)
    assert got == header
    assert bytes(body) == payload
    ref = rfc3550_parse(packet)
    for field in dataclasses.fields(RtpHeader):
        assert ref[field.name] == getattr(header, field.name), field.name
    assert ref["payload"] == payload


def test_known_wire_bytes() -> None:
    header = RtpHeader(sequence=0x1234, timestamp=0xDEADBEEF, ssrc=0x534B0100, marker=True, payload_type=26)
    # V=2 P=0 X=0 CC=0 -> 0x80; M=1 PT=26 -> 0x80 | 0x1A = 0x9A
    assert pack_frame(header, b"AB") == bytes.fromhex("809A1234DEADBEEF534B0100") + b"AB"
    header = dataclasses.replace(header, marker=False, payload_type=127)
    assert pack_frame(header, b"")[:2] == bytes([0x80, 0x7F])


def test_defaults_are_the_dynamic_skynet_type_with_marker() -> None:
    # our payload is not RFC 2435 JPEG, so the default is the dynamic type 96 (x-skynet-frame), never 26
    h = RtpHeader(sequence=5, timestamp=6, ssrc=7)
    assert (h.version, h.payload_type, h.marker, h.padding, h.extension, h.csrc_count) == (2, 96, True, False, False, 0)
    assert SKYNET_PAYLOAD_TYPE == 96 and 96 <= SKYNET_PAYLOAD_TYPE <= 127 and SKYNET_ENCODING_NAME == "x-skynet-frame"


@pytest.mark.parametrize(
    "kwargs",
    [
        {"sequence": 65536},
        {"sequence": -1},
        {"timestamp": 2**32},
        {"ssrc": -1},
        {"payload_type": 128},
        {"version": 1},
        {"csrc_count": 16},
        {"marker": 1},
        {"sequence": 1.0},
        {"sequence": True},
    ],
)
def test_header_rejects_out_of_range(kwargs: dict) -> None:
    base = {"sequence": 1, "timestamp": 2, "ssrc": 3}
    with pytest.raises(RtpError):
        RtpHeader(**{**base, **kwargs})


def test_header_accepts_numpy_ints_as_python_ints() -> None:
    h = RtpHeader(sequence=np.uint16(65535), timestamp=np.uint32(7), ssrc=np.int64(9))
    assert type(h.sequence) is int and h == RtpHeader(65535, 7, 9)


def test_rtp_error_is_a_value_error() -> None:
    assert issubclass(RtpError, ValueError)


def test_pack_rejects_flags_it_cannot_emit() -> None:
    for field in ({"padding": True}, {"extension": True}, {"csrc_count": 2}):
        with pytest.raises(RtpError):
            pack_frame(RtpHeader(1, 2, 3, **field), b"x")
    with pytest.raises(RtpError):
        pack_frame((1, 2, 3), b"x")  # type: ignore[arg-type]
    with pytest.raises(RtpError):
        pack_frame(RtpHeader(1, 2, 3), "text")  # type: ignore[arg-type]


# ------------------------------------------------------------------------------- unpack


def fixed(first: int = 0x80, second: int = 0x9A) -> bytes:
    return bytes([first, second, 0x00, 0x05, 0, 0, 0x01, 0x00, 0x53, 0x4B, 0x01, 0x00])


def test_unpack_skips_csrc_list() -> None:
    csrcs = bytes.fromhex("0000000A" "0000000B")
    packet = fixed(first=0x82) + csrcs + b"payload"
    header, body = unpack_frame(packet)
    assert header.csrc_count == 2 and bytes(body) == b"payload"
    assert rfc3550_parse(packet)["payload"] == b"payload"


def test_unpack_skips_extension_header() -> None:
    ext = bytes.fromhex("BEDE" "0002") + bytes(8)  # profile 0xBEDE, 2 words of data
    packet = fixed(first=0x90) + ext + b"jpeg"
    header, body = unpack_frame(packet)
    assert header.extension and bytes(body) == b"jpeg"


def test_unpack_csrc_extension_and_padding_together() -> None:
    packet = fixed(first=0x80 | 0x20 | 0x10 | 0x01) + bytes(4) + bytes.fromhex("10000001") + bytes(4)
    packet += b"image" + b"\x00\x00\x03"  # 3 octets of padding, the last one counting them
    header, body = unpack_frame(packet)
    assert (header.padding, header.extension, header.csrc_count) == (True, True, 1)
    assert bytes(body) == b"image"
    assert rfc3550_parse(packet)["payload"] == b"image"


def test_padding_can_consume_whole_payload() -> None:
    header, body = unpack_frame(fixed(first=0xA0) + b"\x00\x00\x00\x04")
    assert header.padding and bytes(body) == b""


def test_payload_is_a_zero_copy_view() -> None:
    packet = pack_frame(RtpHeader(1, 2, 3), bytes(100_000))
    _, body = unpack_frame(packet)
    assert isinstance(body, memoryview) and body.readonly and body.obj is packet and body.nbytes == 100_000
    _, body = unpack_frame(bytearray(packet))
    assert body.readonly  # a mutable input does not hand out a writable window into it


def test_unpack_accepts_any_flat_buffer() -> None:
    packet = pack_frame(RtpHeader(1, 2, 3), b"abcd")
    assert unpack_frame(memoryview(packet).cast("B", (4, 4)))[0] == RtpHeader(1, 2, 3)
    strided = memoryview(bytes(b for b in packet for _ in (0, 1)))[::2]
    assert bytes(unpack_frame(strided)[1]) == b"abcd"


@pytest.mark.parametrize(
    "packet, message",
    [
        (b"", "too short"),
        (fixed()[:11], "too short"),
        (bytes([0x40]) + fixed()[1:], "version"),
        (bytes([0x00]) + fixed()[1:], "version"),
        (bytes([0xC0]) + fixed()[1:], "version"),
        (fixed(first=0x83) + bytes(8), "CSRC"),
        (fixed(first=0x90) + b"\xbe\xde", "extension"),
        (fixed(first=0x90) + bytes.fromhex("BEDE0002") + bytes(7), "extension"),
        (fixed(first=0x91) + bytes.fromhex("BEDE0000"), "extension"),  # those 4 bytes are the CSRC
        (fixed(first=0xA0), "padding"),
        (fixed(first=0xA0) + b"abc\x00", "padding"),
        (fixed(first=0xA0) + b"abc\x05", "padding"),
        (fixed(first=0xB0) + bytes.fromhex("BEDE0000") + b"\x02", "padding"),
    ],
    ids=lambda v: v if isinstance(v, str) else f"{len(v)}B",
)
def test_unpack_rejects_malformed(packet: bytes, message: str) -> None:
    with pytest.raises(RtpError, match=message):
        unpack_frame(packet)


@pytest.mark.parametrize("bad", [None, "80 9a", 12, [0x80] * 12])
def test_unpack_rejects_non_bytes(bad) -> None:
    with pytest.raises(RtpError):
        unpack_frame(bad)


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=80))
def test_random_bytes_give_header_or_rtp_error(data: bytes) -> None:
    try:
        header, body = unpack_frame(data)
    except RtpError:
        return
    assert isinstance(header, RtpHeader)
    ref = rfc3550_parse(data)
    assert ref["payload"] == bytes(body)
    assert ref["sequence"] == header.sequence and ref["ssrc"] == header.ssrc


@settings(max_examples=300, deadline=None)
@given(
    first=st.integers(0, 255).map(lambda b: (b & 0x3F) | 0x80),  # version 2, random P X CC
    second=st.integers(0, 255),
    tail=st.binary(max_size=120),
)
def test_version2_random_flags_parse_like_the_independent_reader(first: int, second: int, tail: bytes) -> None:
    data = bytes([first, second]) + bytes(range(10)) + tail
    try:
        header, body = unpack_frame(data)
    except RtpError:
        # rejected only when the CSRC list, extension or padding really does not fit
        cc = first & 0x0F
        off = 12 + 4 * cc
        fits = off <= len(data)
        if fits and first & 0x10:
            fits = off + 4 <= len(data) and off + 4 + 4 * ((data[off + 2] << 8) | data[off + 3]) <= len(data)
            off = off + 4 + 4 * ((data[off + 2] << 8) | data[off + 3]) if fits else off
        if fits and first & 0x20:
            fits = len(data) > off and 1 <= data[-1] <= len(data) - off
        assert not fits
        return
    ref = rfc3550_parse(data)
    assert bytes(body) == ref["payload"]
    assert (header.marker, header.payload_type) == (ref["marker"], ref["payload_type"])


@settings(max_examples=200, deadline=None)
@given(
    seq=st.integers(0, 65535),
    ts=st.integers(0, 2**32 - 1),
    ssrc=st.integers(0, 2**32 - 1),
    marker=st.booleans(),
    pt=st.integers(0, 127),
    payload=st.binary(max_size=64),
)
def test_round_trip_property(seq: int, ts: int, ssrc: int, marker: bool, pt: int, payload: bytes) -> None:
    header = RtpHeader(sequence=seq, timestamp=ts, ssrc=ssrc, marker=marker, payload_type=pt)
    packet = pack_frame(header, payload)
    got, body = unpack_frame(packet)
    assert got == header and bytes(body) == payload
    ref = rfc3550_parse(packet)
    assert (ref["sequence"], ref["timestamp"], ref["ssrc"], ref["marker"], ref["payload_type"]) == (
        seq, ts, ssrc, marker, pt)


# ------------------------------------------------------------------------------- arithmetic


def test_sequence_wraps_at_65535() -> None:
    assert seq_add(65535, 1) == 0
    assert seq_add(65530, 10) == 4
    assert seq_add(3, -5) == 65534
    assert seq_add(0, 65536) == 0
    assert seq_diff(0, 65535) == 1
    assert seq_diff(65535, 0) == -1
    assert seq_diff(4, 65530) == 10
    assert seq_lt(65535, 0) and seq_gt(0, 65535)
    assert seq_lt(65000, 100) and not seq_lt(100, 65000)
    assert not seq_lt(7, 7) and not seq_gt(7, 7)


def test_seq_diff_range_edges() -> None:
    assert seq_diff(32767, 0) == 32767
    assert seq_diff(32768, 0) == -32768  # half the circle: RFC 1982 leaves it undefined
    assert seq_diff(0, 32768) == -32768


@given(st.integers(0, 65535), st.integers(-32768, 32767))
def test_seq_add_and_diff_are_inverse(a: int, n: int) -> None:
    b = seq_add(a, n)
    assert 0 <= b <= 65535
    assert seq_diff(b, a) == n
    if n != -32768:
        assert seq_diff(a, b) == -n
        assert seq_lt(a, b) == (n > 0) and seq_gt(a, b) == (n < 0)


@given(st.integers(0, 2**32 - 1), st.integers(-(2**31), 2**31 - 1))
def test_ts_add_and_diff_are_inverse(a: int, n: int) -> None:
    assert ts_diff(ts_add(a, n), a) == n


def test_ts_wrap() -> None:
    assert ts_add(2**32 - 1, 1) == 0
    assert ts_diff(5, 2**32 - 5) == 10


@pytest.mark.parametrize("call", [
    lambda: seq_add(65536, 1), lambda: seq_add(-1, 1), lambda: seq_diff(1, 70000),
    lambda: seq_lt(1.5, 2), lambda: ts_diff(2**32, 0), lambda: ts_add(-1, 0), lambda: seq_add(None, 1),
])
def test_arithmetic_rejects_out_of_range(call) -> None:
    with pytest.raises(ValueError):
        call()


def test_unwrap_sequence_matches_a_step_by_step_unwrap() -> None:
    rng = np.random.default_rng(3)
    steps = rng.integers(-50, 200, size=2000)
    true_ext = 65000 + np.cumsum(steps)
    seqs = true_ext % 65536
    got = unwrap_sequence(seqs)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, true_ext - true_ext[0] + seqs[0])
    assert unwrap_sequence([]).size == 0
    for bad in ([70000], [[1, 2]], [1.5, 2.0], [-1]):
        with pytest.raises(ValueError):
            unwrap_sequence(bad)


def test_media_timestamp() -> None:
    assert media_timestamp(0.0) == 0
    assert media_timestamp(1.0) == 90_000
    assert media_timestamp(1 / 30) == 3000
    assert media_timestamp(0.5, clock_rate=8000) == 4000
    period = 2**32 / 90_000  # the 90 kHz clock wraps every ~13.25 h
    assert media_timestamp(period + 1.0) == 90_000
    assert media_timestamp(-1 / 90_000) == 2**32 - 1
    epoch_like = 1_763_766_000.25  # a Unix time: stays exact to the tick
    assert media_timestamp(epoch_like) == round(epoch_like * 90_000) % 2**32
    for bad_t in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError):
            media_timestamp(bad_t)
    for bad_rate in (0, -90_000, 90_000.0, True):
        with pytest.raises(ValueError):
            media_timestamp(1.0, clock_rate=bad_rate)


# ------------------------------------------------------------------------------- sender


def test_sender_sequence_wraps_and_stamps_capture_time() -> None:
    sender = RtpSender(ssrc_for(2), initial_seq=65534)
    packets = [sender.frame(b"jpg%d" % i, capture_time_s=10.0 + i / 30) for i in range(4)]
    headers = [unpack_frame(p)[0] for p in packets]
    assert [h.sequence for h in headers] == [65534, 65535, 0, 1]
    assert [h.timestamp for h in headers] == [900_000 + 3000 * i for i in range(4)]
    assert all(h.ssrc == 0x534B0200 and h.marker and h.payload_type == SKYNET_PAYLOAD_TYPE for h in headers)
    assert sender.next_sequence == 2
    assert (sender.packets_sent, sender.octets_sent) == (4, 16)
    assert bytes(unpack_frame(packets[2])[1]) == b"jpg2"


def test_sender_marker_and_payload_type() -> None:
    sender = RtpSender(ssrc=5, payload_type=96, clock_rate=8000, initial_seq=0)
    h, _ = unpack_frame(sender.frame(b"", 0.25, marker=False))
    assert (h.marker, h.payload_type, h.timestamp) == (False, 96, 2000)


def test_sender_random_initial_sequence_is_reproducible_with_rng() -> None:
    a = RtpSender(1, rng=np.random.default_rng(42)).next_sequence
    b = RtpSender(1, rng=np.random.default_rng(42)).next_sequence
    assert a == b and 0 <= a <= 65535
    starts = {RtpSender(1, rng=np.random.default_rng(s)).next_sequence for s in range(20)}
    assert len(starts) > 10  # really drawn, not a constant


@pytest.mark.parametrize("kwargs", [
    {"ssrc": -1}, {"ssrc": 2**32}, {"ssrc": 1, "payload_type": 128}, {"ssrc": 1, "clock_rate": 0},
    {"ssrc": 1, "initial_seq": 65536},
])
def test_sender_rejects_bad_parameters(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        RtpSender(**kwargs)


def test_sender_rejects_bad_frame_input() -> None:
    sender = RtpSender(1, initial_seq=0)
    with pytest.raises(ValueError):
        sender.frame(b"x", math.nan)
    with pytest.raises(RtpError):
        sender.frame("not bytes", 0.0)  # type: ignore[arg-type]
    assert sender.next_sequence == 0  # a refused frame does not consume a sequence number
    assert sender.packets_sent == 0


def test_sender_header_preview_matches_the_packet() -> None:
    sender = RtpSender(ssrc_for(4, 2), initial_seq=65535)
    preview = sender.header(3.0, marker=False)
    assert sender.next_sequence == 65535  # a preview does not consume the number
    assert unpack_frame(sender.frame(b"img", 3.0, marker=False))[0] == preview


def test_ssrc_mapping() -> None:
    assert ssrc_for(1) == 0x534B0100
    assert ssrc_for(255, 255) == 0x534BFFFF
    seen = {ssrc_for(u, c) for u in range(1, 256) for c in range(4)}
    assert len(seen) == 255 * 4
    for u, c in [(1, 0), (3, 1), (255, 255)]:
        assert parse_ssrc(ssrc_for(u, c)) == (u, c)
    for bad in [(0, 0), (256, 0), (1, -1), (1, 256), (True, 0), (1.0, 0)]:
        with pytest.raises(ValueError):
            ssrc_for(*bad)
    for foreign in (0, 0x12340100, 0x534B0001):
        with pytest.raises(ValueError):
            parse_ssrc(foreign)
