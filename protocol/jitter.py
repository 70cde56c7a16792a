"""Receiver-side jitter buffer and reception statistics (RFC 3550 A.1, A.3, A.8) for RTP-style imagery frames.

Design notes: docs/imagery.md (protocol/jitter.py).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from protocol.rtp import SEQ_MOD, VIDEO_CLOCK_RATE, RtpHeader, seq_delta, ts_delta, unpack_frame

__all__ = ["MAX_DROPOUT", "Frame", "JitterBuffer", "JitterBuffers", "JitterStats"]

MAX_DROPOUT = 3000  # RFC 3550 A.1: the largest forward jump still taken as loss
MAX_CAPACITY = 1 << 14  # the window must stay well inside half the 16-bit circle
_SEQ_MASK = SEQ_MOD - 1


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame released for playout: the header and payload as pushed (a reference, never a copy), its
    arrival time and its extended sequence number (RFC 3550 A.1; monotonic within a numbering epoch)."""

    header: RtpHeader
    payload: bytes | memoryview
    arrival_s: float
    extended_sequence: int

    @property
    def sequence(self) -> int:
        return self.header.sequence

    @property
    def timestamp(self) -> int:
        return self.header.timestamp

    @property
    def ssrc(self) -> int:
        return self.header.ssrc

    @property
    def marker(self) -> bool:
        return self.header.marker


@dataclass(frozen=True, slots=True)
class JitterStats:
    """Receiver statistics of one source (RFC 3550, 6.4.1 and appendix A; the classification of
    ``duplicated``, ``late``, ``reordered`` and ``resyncs``: docs/imagery.md, "The jitter buffer")."""

    ssrc: int | None
    received: int  # every packet pushed (A.3)
    delivered: int
    lost: int  # the numbers playout gave up (a frame arriving after that is also late)
    duplicated: int
    late: int
    reordered: int
    resyncs: int
    buffered: int
    highest_sequence: int | None  # extended (A.1)
    expected: int  # summed over the numbering epochs (A.3)
    fraction_lost: float  # lost / expected over the session
    cumulative_lost: int  # expected - received (A.3, negative with duplicates)
    jitter_ts: float  # J of A.8, in timestamp units
    jitter_s: float  # J in seconds

    def as_dict(self) -> dict[str, Any]:
        """Plain dict (for messages and JSON)."""
        return asdict(self)


def _check_params(capacity: int, playout_delay_s: float, clock_rate: int) -> tuple[int, float, int]:
    if isinstance(capacity, bool) or not isinstance(capacity, (int, np.integer)) or not 1 <= capacity <= MAX_CAPACITY:
        raise ValueError(f"capacity must be an int in 1..{MAX_CAPACITY}, got {capacity!r}")
    delay = float(playout_delay_s)
    if not math.isfinite(delay) or delay < 0:
        raise ValueError(f"playout_delay_s must be finite and >= 0, got {playout_delay_s!r}")
    if isinstance(clock_rate, bool) or not isinstance(clock_rate, (int, np.integer)) or clock_rate <= 0:
        raise ValueError(f"clock_rate must be a positive int, got {clock_rate!r}")
    return int(capacity), delay, int(clock_rate)


def _arrival(arrival_s: float) -> float:
    try:
        t = float(arrival_s)
    except (TypeError, ValueError):
        raise ValueError(f"arrival time must be a number of seconds, got {arrival_s!r}") from None
    if not math.isfinite(t):
        raise ValueError(f"arrival time must be finite, got {arrival_s!r}")
    return t


class JitterBuffer:
    """Reordering playout buffer and RFC 3550 receiver statistics for one SSRC.

    ``capacity`` (1..16384) is the reorder window beyond the next frame to play; ``playout_delay_s`` how
    long a missing frame is waited for (0: no reordering); ``release_late`` also returns a packet arriving
    after its number was given up (counted ``late``). docs/imagery.md, "The jitter buffer".

    >>> from protocol.rtp import RtpHeader
    >>> jb = JitterBuffer(capacity=8, playout_delay_s=0.1)
    >>> [f.sequence for f in jb.push(RtpHeader(65535, 0, 7), b"a", 0.00)]
    [65535]
    >>> jb.push(RtpHeader(1, 6000, 7), b"c", 0.07)   # 0 is missing: held
    []
    >>> [f.sequence for f in jb.push(RtpHeader(0, 3000, 7), b"b", 0.08)]
    [0, 1]
    >>> jb.stats().reordered, jb.stats().highest_sequence
    (1, 65537)
    """

    def __init__(self, capacity: int = 64, playout_delay_s: float = 0.1, clock_rate: int = VIDEO_CLOCK_RATE,
                 release_late: bool = False) -> None:
        self.capacity, self.playout_delay_s, self.clock_rate = _check_params(capacity, playout_delay_s, clock_rate)
        #: hand a late packet (its number already given up) out anyway, after the frames in order:
        #: for media where every frame counts whatever its order (inspection captures); counted late
        self.release_late = bool(release_late)
        self.late_released = 0
        cap = self.capacity
        self._late_out: list[Frame] = []
        self._slots: list[Frame | None] = [None] * cap
        self._arrivals = np.full(cap, np.inf)  # arrival time per occupied slot, inf when empty
        self._played = np.full(cap, -1, dtype=np.int64)  # extended seq last played per slot
        self._buffered = 0
        self._ssrc: int | None = None
        self._started = False  # a first frame was stored
        self._next = 0  # extended sequence number to play next (once started)
        self._max: int = -1  # extended highest sequence number stored
        self._base: int = 0  # first extended sequence number of the epoch
        self._expected_prior = 0  # expected count of finished epochs
        self._probe: tuple[RtpHeader, bytes | memoryview, float] | None = None
        self._last_arrival = 0.0  # R_i of the previous packet, seconds
        self._last_ts: int | None = None  # S_i of the previous packet
        self._jitter = 0.0  # J, timestamp units
        self.received = self.delivered = self.lost = 0
        self.duplicated = self.late = self.reordered = self.resyncs = 0

    # ---------------------------------------------------------------- public API

    @property
    def ssrc(self) -> int | None:
        return self._ssrc

    def __len__(self) -> int:
        return self._buffered + (self._probe is not None)

    def push(self, header: RtpHeader, payload: bytes | memoryview, arrival_s: float) -> list[Frame]:
        """Take one packet arriving at ``arrival_s`` ("now": expired gaps are given up as by :meth:`pop_due`);
        return the frames ready for playout in sequence order. ValueError for another SSRC or bad input."""
        if not isinstance(header, RtpHeader):
            raise ValueError(f"header must be an RtpHeader, got {type(header).__name__}")
        if not isinstance(payload, (bytes, bytearray, memoryview)):
            raise ValueError(f"payload must be bytes-like, got {type(payload).__name__}")
        now = _arrival(arrival_s)
        if self._ssrc is None:
            self._ssrc = header.ssrc
        elif header.ssrc != self._ssrc:
            raise ValueError(
                f"this JitterBuffer serves SSRC {self._ssrc:#010x}, got {header.ssrc:#010x}; use JitterBuffers"
            )
        self.received += 1
        out: list[Frame] = []
        if not self._started:
            self._start_epoch(header.sequence)
            self._jitter_reference(header.timestamp, now)
            self._store(header, payload, now, header.sequence)
        else:
            self._accept(header, payload, now, out)
        self._release(now, out)
        if self._late_out:
            out += self._late_out
            self._late_out = []
        return out

    def push_packet(self, data: bytes | bytearray | memoryview, arrival_s: float) -> list[Frame]:
        """:func:`~protocol.rtp.unpack_frame` then :meth:`push`; RtpError for a bad packet."""
        header, payload = unpack_frame(data)
        return self.push(header, payload, arrival_s)

    def pop_due(self, now_s: float) -> list[Frame]:
        """Release the frames whose wait has ended by ``now_s``, giving up expired gaps."""
        out: list[Frame] = []
        self._release(_arrival(now_s), out)
        return out

    def flush(self) -> list[Frame]:
        """Release everything held, in order; remaining gaps count as lost, a probe resyncs."""
        out: list[Frame] = []
        self._release(None, out)
        return out

    def next_deadline(self) -> float | None:
        """Earliest time at which :meth:`pop_due` would release something; None if never."""
        deadline = math.inf
        if self._buffered:
            deadline = float(self._arrivals.min()) + self.playout_delay_s
        if self._probe is not None:
            deadline = min(deadline, self._probe[2] + self.playout_delay_s)
        return None if deadline == math.inf else deadline

    def stats(self) -> JitterStats:
        """Current statistics (a snapshot)."""
        started = self._started
        expected = self._expected_prior + (self._max - self._base + 1 if started else 0)
        return JitterStats(ssrc=self._ssrc, received=self.received, delivered=self.delivered, lost=self.lost,
                           duplicated=self.duplicated, late=self.late, reordered=self.reordered, resyncs=self.resyncs,
                           buffered=len(self), highest_sequence=self._max if started else None, expected=expected,
                           fraction_lost=self.lost / expected if expected else 0.0,
                           cumulative_lost=expected - self.received, jitter_ts=self._jitter,
                           jitter_s=self._jitter / self.clock_rate)

    # ---------------------------------------------------------------- internals

    def _extend(self, seq: int) -> int:
        """Extended sequence number of ``seq``: the nearest to the highest seen (RFC 3550 A.1)."""
        top = self._max
        return top + seq_delta(seq, top & _SEQ_MASK)

    def _start_epoch(self, ext: int) -> None:
        self._base = self._next = ext
        self._max = ext - 1
        self._started = True
        self._played.fill(-1)

    def _jitter_reference(self, ts: int, now: float) -> None:
        self._last_ts, self._last_arrival = ts, now

    def _update_jitter(self, ts: int, now: float) -> None:
        """RFC 3550 A.8: D = (Rj - Ri) - (Sj - Si) in timestamp units; J += (|D| - J) / 16."""
        if self._last_ts is not None:
            ds = ts_delta(ts, self._last_ts)
            d = (now - self._last_arrival) * self.clock_rate - ds
            self._jitter += (abs(d) - self._jitter) / 16.0
        self._jitter_reference(ts, now)

    def _accept(self, header: RtpHeader, payload: bytes | memoryview, now: float, out: list[Frame]) -> None:
        cap, nxt = self.capacity, self._next
        ext = self._extend(header.sequence)
        if nxt - cap <= ext < nxt + cap or (ext >= nxt + cap and ext - self._max <= cap):
            if self._probe is not None:  # the stream went on in the old window: a stray
                self._probe = None
                self.late += 1
            self._update_jitter(header.timestamp, now)
            if ext < nxt:
                if self._played[ext % cap] == ext:
                    self.duplicated += 1
                else:
                    self.late += 1
                    if self.release_late:
                        self.late_released += 1
                        self._late_out.append(Frame(header, payload, now, ext))
                return
            if ext >= nxt + cap:  # window full of frames waiting for gaps: give the oldest up
                self._advance_to(ext - cap + 1, out)
            slot = self._slots[ext % cap]
            if slot is not None:
                self.duplicated += 1
                return
            if ext < self._max:
                self.reordered += 1
            self._store(header, payload, now, ext)
            return
        probe = self._probe
        if probe is not None and header.sequence == probe[0].sequence:
            self.duplicated += 1
            return
        if probe is not None and seq_delta(header.sequence, probe[0].sequence) == 1:
            self._probe = None
            self._resync(probe, out)
            self._update_jitter(header.timestamp, now)
            self._store(header, payload, now, self._extend(header.sequence))
            return
        if probe is not None:  # two unrelated far-off packets: the older one was a stray
            self.late += 1
        self._probe = (header, payload, now)

    def _store(self, header: RtpHeader, payload: bytes | memoryview, now: float, ext: int) -> None:
        i = ext % self.capacity
        self._slots[i] = Frame(header, payload, now, ext)
        self._arrivals[i] = now
        self._buffered += 1
        if ext > self._max:
            self._max = ext

    def _advance_to(self, target: int, out: list[Frame]) -> None:
        """Play or give up every number below ``target`` (extended)."""
        cap, slots = self.capacity, self._slots
        e = self._next
        while e < target:
            if self._buffered == 0:  # nothing more held: the rest are gaps
                self.lost += target - e
                e = target
                break
            i = e % cap
            f = slots[i]
            if f is None:
                self.lost += 1
            else:
                slots[i] = None
                self._arrivals[i] = np.inf
                self._buffered -= 1
                self._played[i] = e
                self.delivered += 1
                out.append(f)
            e += 1
        self._next = e

    def _release(self, now: float | None, out: list[Frame]) -> None:
        """Play in-order frames; give up gaps whose wait has expired (all gaps if ``now`` is None)."""
        cap, slots = self.capacity, self._slots
        while self._buffered:
            e = self._next
            i = e % cap
            f = slots[i]
            if f is not None:
                slots[i] = None
                self._arrivals[i] = np.inf
                self._buffered -= 1
                self._played[i] = e
                self._next = e + 1
                self.delivered += 1
                out.append(f)
                continue
            if now is not None and float(self._arrivals.min()) + self.playout_delay_s > now:
                break
            k = 1  # the lowest buffered frame is k numbers ahead
            while slots[(e + k) % cap] is None:
                k += 1
            self.lost += k
            self._next = e + k
        probe = self._probe
        if probe is not None and (now is None or probe[2] + self.playout_delay_s <= now):
            self._probe = None
            self._resync(probe, out)

    def _resync(self, probe: tuple[RtpHeader, bytes | memoryview, float], out: list[Frame]) -> None:
        """Restart playout at ``probe`` after a jump (docs/imagery.md, "The jitter buffer")."""
        header, payload, arrival = probe
        self.resyncs += 1
        self._advance_to(self._max + 1, out)  # release everything held from the old window
        ext = self._extend(header.sequence)
        if 0 <= ext - self._next < MAX_DROPOUT:
            self.lost += ext - self._next  # an outage longer than the window: same numbering
            self._next = ext
        else:  # a new numbering epoch (RFC 3550 A.1 init_seq)
            self._expected_prior += self._max - self._base + 1
            ext = header.sequence
            self._start_epoch(ext)
        self._jitter_reference(header.timestamp, arrival)
        self._store(header, payload, arrival, ext)
        self._release(arrival, out)


class JitterBuffers:
    """One :class:`JitterBuffer` per SSRC, created on a source's first packet; a new source beyond
    ``max_sources`` raises ValueError (forged SSRCs must not grow memory without bound)."""

    def __init__(self, capacity: int = 64, playout_delay_s: float = 0.1, clock_rate: int = VIDEO_CLOCK_RATE,
                 max_sources: int = 64, release_late: bool = False) -> None:
        self._params = (*_check_params(capacity, playout_delay_s, clock_rate), bool(release_late))
        if isinstance(max_sources, bool) or not isinstance(max_sources, int) or max_sources < 1:
            raise ValueError(f"max_sources must be a positive int, got {max_sources!r}")
        self.max_sources = max_sources
        self._buffers: dict[int, JitterBuffer] = {}

    def __len__(self) -> int:
        return len(self._buffers)

    def __contains__(self, ssrc: int) -> bool:
        return ssrc in self._buffers

    def __getitem__(self, ssrc: int) -> JitterBuffer:
        return self._buffers[ssrc]

    @property
    def sources(self) -> list[int]:
        return list(self._buffers)

    def push(self, header: RtpHeader, payload: bytes | memoryview, arrival_s: float) -> list[Frame]:
        """Route to the source's buffer (created if new); see :meth:`JitterBuffer.push`."""
        if not isinstance(header, RtpHeader):
            raise ValueError(f"header must be an RtpHeader, got {type(header).__name__}")
        jb = self._buffers.get(header.ssrc)
        if jb is None:
            if len(self._buffers) >= self.max_sources:
                raise ValueError(
                    f"too many RTP sources (max_sources={self.max_sources}); SSRC {header.ssrc:#010x} refused"
                )
            _arrival(arrival_s)  # do not create a buffer for a packet push() will refuse
            jb = self._buffers[header.ssrc] = JitterBuffer(*self._params)
        return jb.push(header, payload, arrival_s)

    def push_packet(self, data: bytes | bytearray | memoryview, arrival_s: float) -> list[Frame]:
        """:func:`~protocol.rtp.unpack_frame` then :meth:`push`; RtpError for a bad packet."""
        header, payload = unpack_frame(data)
        return self.push(header, payload, arrival_s)

    def pop_due(self, now_s: float) -> list[Frame]:
        """Due frames of every source (each source's frames in sequence order)."""
        now = _arrival(now_s)
        return [f for jb in self._buffers.values() for f in jb.pop_due(now)]

    def flush(self) -> list[Frame]:
        """Everything held by every source, each source in sequence order."""
        return [f for jb in self._buffers.values() for f in jb.flush()]

    def remove(self, ssrc: int) -> list[Frame]:
        """Forget a source (e.g. after RTCP BYE or a liveliness loss); returns its last frames."""
        jb = self._buffers.pop(ssrc, None)
        return jb.flush() if jb is not None else []

    def next_deadline(self) -> float | None:
        """Earliest deadline over all sources, None if none."""
        deadlines = [d for jb in self._buffers.values() if (d := jb.next_deadline()) is not None]
        return min(deadlines) if deadlines else None

    def stats(self) -> dict[int, JitterStats]:
        """Statistics per SSRC."""
        return {ssrc: jb.stats() for ssrc, jb in self._buffers.items()}
