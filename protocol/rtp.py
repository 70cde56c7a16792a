"""RTP-style sequenced frames for the imagery link class (RFC 3550 fixed header).

Design notes: docs/imagery.md (protocol/rtp.py).
"""

from __future__ import annotations

import math
import struct
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["JPEG_PAYLOAD_TYPE", "SKYNET_ENCODING_NAME", "SKYNET_PAYLOAD_TYPE", "RTP_HEADER_LENGTH", "RTP_VERSION",
           "VIDEO_CLOCK_RATE", "RtpError", "RtpHeader", "RtpSender", "SeenFrames", "media_timestamp", "pack_frame", "parse_ssrc",
           "seq_add", "seq_delta", "seq_diff", "seq_gt", "seq_lt", "ssrc_for", "ts_add", "ts_delta", "ts_diff",
           "unpack_frame", "unwrap_sequence"]

RTP_VERSION = 2
RTP_HEADER_LENGTH = 12
JPEG_PAYLOAD_TYPE = 26  # RFC 3551, table 5: JPEG (RFC 2435 payload), clock 90 kHz
SKYNET_PAYLOAD_TYPE = 96  # dynamic (RFC 3551, section 3): the project's own frame format
SKYNET_ENCODING_NAME = "x-skynet-frame"  # its SDP encoding name (rtpmap), clock 90 kHz
VIDEO_CLOCK_RATE = 90_000  # RFC 3551, section 5

SEQ_MOD = 1 << 16
TS_MOD = 1 << 32
_SEQ_MASK = SEQ_MOD - 1
_TS_MASK = TS_MOD - 1
_SEQ_HALF = SEQ_MOD >> 1
_TS_HALF = TS_MOD >> 1

_HEADER = struct.Struct("!BBHII")
_EXT_HEADER = struct.Struct("!HH")

SSRC_TAG = 0x534B  # "SK": upper 16 bits of every SkyNet camera SSRC


class RtpError(ValueError):
    """A packet or header that is not valid RTP (RFC 3550, section 5.1)."""


# ------------------------------------------------- serial-number arithmetic (RFC 1982): sequence numbers and timestamps


def _check_u(value: int, mask: int, what: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{what} must be an int, got {type(value).__name__}")
    if not 0 <= value <= mask:
        raise ValueError(f"{what} must be in 0..{mask}, got {value}")


def seq_delta(a: int, b: int) -> int:
    """:func:`seq_diff` without the range checks, for the hot path of callers whose sequence numbers
    are already known to be 16-bit (parsed headers): the one home of the RFC 1982 arithmetic."""
    return ((a - b + _SEQ_HALF) & _SEQ_MASK) - _SEQ_HALF


def ts_delta(a: int, b: int) -> int:
    """:func:`ts_diff` without the range checks (timestamps of parsed headers)."""
    return ((a - b + _TS_HALF) & _TS_MASK) - _TS_HALF


def seq_add(a: int, n: int) -> int:
    """Sequence number ``a`` advanced by ``n`` (any sign), modulo 2**16 (RFC 1982, 3.1).

    >>> seq_add(65535, 1)
    0
    >>> seq_add(0, -1)
    65535
    """
    _check_u(a, _SEQ_MASK, "sequence number")
    return (a + int(n)) & _SEQ_MASK


def seq_diff(a: int, b: int) -> int:
    """Signed distance ``a - b`` between two 16-bit sequence numbers, the short way round (RFC 1982, 3.2);
    -32768 for both orders at exactly half the circle, where RFC 1982 leaves it undefined.

    >>> seq_diff(2, 65534)
    4
    >>> seq_diff(65534, 2)
    -4
    """
    _check_u(a, _SEQ_MASK, "sequence number")
    _check_u(b, _SEQ_MASK, "sequence number")
    return seq_delta(a, b)


def seq_lt(a: int, b: int) -> bool:
    """``a`` precedes ``b`` in 16-bit serial-number order (RFC 1982, section 3.2)."""
    return seq_diff(a, b) < 0


def seq_gt(a: int, b: int) -> bool:
    """``a`` follows ``b`` in 16-bit serial-number order (RFC 1982, section 3.2)."""
    return seq_diff(a, b) > 0


def ts_add(a: int, n: int) -> int:
    """32-bit RTP timestamp ``a`` advanced by ``n`` ticks, modulo 2**32."""
    _check_u(a, _TS_MASK, "timestamp")
    return (a + int(n)) & _TS_MASK


def ts_diff(a: int, b: int) -> int:
    """Signed distance ``a - b`` between two 32-bit RTP timestamps, so that a wrap (every 13.25 h at
    90 kHz) makes no jump in the interarrival jitter (RFC 3550, A.8)."""
    _check_u(a, _TS_MASK, "timestamp")
    _check_u(b, _TS_MASK, "timestamp")
    return ts_delta(a, b)


def unwrap_sequence(seqs: np.ndarray | list[int]) -> np.ndarray:
    """Extended sequence numbers (RFC 3550 A.1: cycles * 2**16 + seq, each step the short way round) of
    16-bit sequence numbers in arrival order, relative to the first one's cycle 0; vectorised, for logs.

    >>> unwrap_sequence([65534, 65535, 0, 2, 1]).tolist()
    [65534, 65535, 65536, 65538, 65537]
    """
    s = np.asarray(seqs)
    if s.ndim != 1:
        raise ValueError(f"sequence numbers must be 1-D, got shape {s.shape}")
    if s.size == 0:
        return np.zeros(0, dtype=np.int64)
    if not np.issubdtype(s.dtype, np.integer):
        raise ValueError(f"sequence numbers must be integers, got dtype {s.dtype}")
    s = s.astype(np.int64)
    if s.min() < 0 or s.max() > _SEQ_MASK:
        raise ValueError("sequence numbers must be in 0..65535")
    steps = ((np.diff(s) + _SEQ_HALF) & _SEQ_MASK) - _SEQ_HALF
    out = np.empty_like(s)
    out[0] = s[0]
    np.cumsum(steps, out=out[1:])
    out[1:] += s[0]
    return out


def media_timestamp(t_seconds: float, clock_rate: int = VIDEO_CLOCK_RATE) -> int:
    """RTP media timestamp ``round(t * clock_rate) mod 2**32`` of a capture time in seconds (RFC 3550 5.1;
    90 kHz video clock, RFC 3551 section 5).

    >>> media_timestamp(1.5)
    135000
    >>> media_timestamp(2**32 / 90000)
    0
    """
    if isinstance(clock_rate, bool) or not isinstance(clock_rate, (int, np.integer)) or clock_rate <= 0:
        raise ValueError(f"clock_rate must be a positive int, got {clock_rate!r}")
    t = float(t_seconds)
    if not math.isfinite(t):
        raise ValueError(f"time must be finite, got {t_seconds!r}")
    return math.floor(t * int(clock_rate) + 0.5) & _TS_MASK


# ----------------------------------------------------------------------------- header, pack, unpack


@dataclass(frozen=True, slots=True)
class RtpHeader:
    """The RFC 3550 (section 5.1) fixed header of one packet. ``padding``, ``extension`` and ``csrc_count``
    are the wire bits as received (:func:`unpack_frame` skips what they announce; :func:`pack_frame`
    emits none); our frames are one packet each, so ``marker`` is set."""

    sequence: int
    timestamp: int
    ssrc: int
    marker: bool = True
    payload_type: int = SKYNET_PAYLOAD_TYPE
    version: int = RTP_VERSION
    padding: bool = False
    extension: bool = False
    csrc_count: int = 0

    def __post_init__(self) -> None:
        if self.version != RTP_VERSION:
            raise RtpError(f"RTP version must be 2, got {self.version!r}")
        for name in ("marker", "padding", "extension"):
            if not isinstance(getattr(self, name), bool):
                raise RtpError(f"{name} must be a bool, got {getattr(self, name)!r}")
        for name, mask in (("sequence", _SEQ_MASK), ("timestamp", _TS_MASK), ("ssrc", _TS_MASK), ("payload_type", 0x7F),
                           ("csrc_count", 0x0F)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise RtpError(f"{name} must be an int, got {value!r}")
            if not 0 <= value <= mask:
                raise RtpError(f"{name} must be in 0..{mask}, got {value}")
            if type(value) is not int:
                object.__setattr__(self, name, int(value))


_FIELD_SETTERS = tuple(
    getattr(RtpHeader, name).__set__
    for name in ("sequence", "timestamp", "ssrc", "marker", "payload_type", "version", "padding", "extension",
                 "csrc_count")
)


def _new_header(b0: int, b1: int, seq: int, ts: int, ssrc: int, _set: tuple[Any, ...] = _FIELD_SETTERS) -> RtpHeader:
    # The fields come straight from bit fields of the wire, so they are in range by
    # construction: fill the slots directly and skip __post_init__ (about 3x cheaper).
    h = object.__new__(RtpHeader)
    s_seq, s_ts, s_ssrc, s_m, s_pt, s_v, s_p, s_x, s_cc = _set
    s_seq(h, seq)
    s_ts(h, ts)
    s_ssrc(h, ssrc)
    s_m(h, b1 >= 0x80)
    s_pt(h, b1 & 0x7F)
    s_v(h, RTP_VERSION)
    s_p(h, (b0 & 0x20) != 0)
    s_x(h, (b0 & 0x10) != 0)
    s_cc(h, b0 & 0x0F)
    return h


def pack_frame(header: RtpHeader, payload: bytes | bytearray | memoryview) -> bytes:
    """One frame's bytes: the 12-byte fixed header, then the payload; a header asking for padding,
    extension or CSRCs is refused (``dataclasses.replace`` them to re-send a received header)."""
    if not isinstance(header, RtpHeader):
        raise RtpError(f"header must be an RtpHeader, got {type(header).__name__}")
    if header.padding or header.extension or header.csrc_count:
        raise RtpError("pack_frame emits the fixed header only: padding, extension and csrc_count must be unset")
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise RtpError(f"payload must be bytes-like, got {type(payload).__name__}")
    head = _HEADER.pack(
        0x80,  # V=2, P=0, X=0, CC=0
        (0x80 if header.marker else 0) | header.payload_type,
        header.sequence,
        header.timestamp,
        header.ssrc,
    )
    return b"".join((head, payload))


def unpack_frame(data: bytes | bytearray | memoryview) -> tuple[RtpHeader, memoryview]:
    """Header and read-only zero-copy payload view of one packet (RFC 3550 5.1 and the receiver checks of
    A.1): at least 12 bytes, version 2; the CSRC list and header extension (5.3.1) are skipped and must
    fit; the padding count (P bit) counts itself, at least 1, and must fit. RtpError otherwise."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise RtpError(f"RTP packet must be bytes-like, got {type(data).__name__}")
    view = memoryview(data)
    if not view.c_contiguous:
        view = memoryview(view.tobytes())
    if view.ndim != 1 or view.format != "B":
        view = view.cast("B")
    n = view.nbytes
    if n < RTP_HEADER_LENGTH:
        raise RtpError(f"RTP packet too short: {n} bytes, the fixed header alone is 12")
    b0, b1, seq, ts, ssrc = _HEADER.unpack_from(view, 0)
    if b0 >> 6 != RTP_VERSION:
        raise RtpError(f"RTP version must be 2, got {b0 >> 6}")
    pos = RTP_HEADER_LENGTH + 4 * (b0 & 0x0F)
    if pos > n:
        raise RtpError(f"RTP CSRC list truncated: CC={b0 & 0x0F} needs {pos} bytes, packet has {n}")
    if b0 & 0x10:
        if pos + 4 > n:
            raise RtpError(f"RTP header extension truncated: no room for its 4-byte header at offset {pos}")
        _profile, words = _EXT_HEADER.unpack_from(view, pos)
        pos += 4 + 4 * words
        if pos > n:
            raise RtpError(f"RTP header extension truncated: length {words} words needs {pos} bytes, packet has {n}")
    end = n
    if b0 & 0x20:
        if end == pos:
            raise RtpError("RTP padding bit set but there is no padding octet")
        pad = view[end - 1]
        if pad == 0:
            raise RtpError("RTP padding count is 0; it must count at least the count octet itself")
        if pad > end - pos:
            raise RtpError(f"RTP padding of {pad} octets exceeds the {end - pos} octets after the header")
        end -= pad
    return _new_header(b0, b1, seq, ts, ssrc), view[pos:end].toreadonly()


# ----------------------------------------------------------------------------- sender side


def ssrc_for(uav_id: int, camera: int = 0) -> int:
    """Stable SSRC ``0x534B0000 | uav_id << 8 | camera`` of one camera ("SK", UAV 1..255, camera 0..255):
    unique in a fleet and across restarts, where RFC 3550 section 8 draws random ones.

    >>> hex(ssrc_for(3, 1))
    '0x534b0301'
    """
    for name, value, lo in (("uav_id", uav_id, 1), ("camera", camera, 0)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= 255:
            raise ValueError(f"{name} must be an int in {lo}..255, got {value!r}")
    return (SSRC_TAG << 16) | (int(uav_id) << 8) | int(camera)


def parse_ssrc(ssrc: int) -> tuple[int, int]:
    """Inverse of :func:`ssrc_for`: ``(uav_id, camera)``; ValueError for a foreign SSRC."""
    _check_u(ssrc, _TS_MASK, "ssrc")
    uav, camera = (ssrc >> 8) & 0xFF, ssrc & 0xFF
    if ssrc >> 16 != SSRC_TAG or uav == 0:
        raise ValueError(f"SSRC {ssrc:#010x} is not a SkyNet camera SSRC (0x534BUUCC, UU >= 1)")
    return uav, camera


class RtpSender:
    """Stamps consecutive frames of one source with sequence number and media timestamp; ``initial_seq``
    None draws it at random (RFC 3550, section 5.1).

    >>> s = RtpSender(ssrc_for(1), initial_seq=65535)
    >>> [unpack_frame(s.frame(b"jpeg", t))[0].sequence for t in (0.0, 0.1)]
    [65535, 0]
    """

    __slots__ = ("ssrc", "payload_type", "clock_rate", "_seq", "packets_sent", "octets_sent")

    def __init__(self, ssrc: int, payload_type: int = SKYNET_PAYLOAD_TYPE, clock_rate: int = VIDEO_CLOCK_RATE,
                 initial_seq: int | None = None, rng: np.random.Generator | None = None) -> None:
        _check_u(ssrc, _TS_MASK, "ssrc")
        _check_u(payload_type, 0x7F, "payload_type")
        media_timestamp(0.0, clock_rate)  # validates clock_rate
        if initial_seq is None:
            gen = rng if rng is not None else np.random.default_rng()
            initial_seq = int(gen.integers(0, SEQ_MOD))
        _check_u(initial_seq, _SEQ_MASK, "initial_seq")
        self.ssrc = int(ssrc)
        self.payload_type = int(payload_type)
        self.clock_rate = int(clock_rate)
        self._seq = int(initial_seq)
        self.packets_sent = 0  # RFC 3550 sender report: packet count
        self.octets_sent = 0  # RFC 3550 sender report: payload octet count

    @property
    def next_sequence(self) -> int:
        """The sequence number the next frame will carry."""
        return self._seq

    def header(self, capture_time_s: float, marker: bool = True) -> RtpHeader:
        """Header of the next frame without consuming its sequence number."""
        return RtpHeader(sequence=self._seq, timestamp=media_timestamp(capture_time_s, self.clock_rate), ssrc=self.ssrc,
                         marker=bool(marker), payload_type=self.payload_type)

    def frame(self, payload: bytes | bytearray | memoryview, capture_time_s: float, marker: bool = True) -> bytes:
        """Packet for one encoded image captured at ``capture_time_s`` (s); advances the sequence number."""
        if not isinstance(payload, (bytes, bytearray, memoryview)):
            raise RtpError(f"payload must be bytes-like, got {type(payload).__name__}")
        ts = media_timestamp(capture_time_s, self.clock_rate)
        # every field is validated at construction, so pack directly (no RtpHeader on the hot path)
        head = _HEADER.pack(0x80, (0x80 if marker else 0) | self.payload_type, self._seq, ts, self.ssrc)
        packet = b"".join((head, payload))
        self._seq = (self._seq + 1) & _SEQ_MASK
        self.packets_sent += 1
        self.octets_sent += len(packet) - RTP_HEADER_LENGTH
        return packet


class SeenFrames:
    """The frames already taken, so that a frame two subscriptions deliver is taken once.

    A frame is named by its key and its RTP SSRC and sequence number (RFC 3550 5.1); the last ``memory``
    names are kept, the oldest forgotten first. Not locked: callers hold their own lock.

    >>> seen = SeenFrames(memory=2)
    >>> seen.first("k", 7, 1), seen.first("k", 7, 1), seen.first("j", 7, 1)
    (True, False, True)
    """

    def __init__(self, memory: int = 4096) -> None:
        self.memory = memory
        self._names: OrderedDict[tuple[str, int, int], None] = OrderedDict()

    def first(self, key: str, ssrc: int, sequence: int) -> bool:
        name = (key, ssrc, sequence & _SEQ_MASK)
        if name in self._names:
            return False
        self._names[name] = None
        if len(self._names) > self.memory:
            self._names.popitem(last=False)
        return True
