"""Per-source rate and size budgets on what a subscriber accepts.

Every key a role may write (:mod:`protocol.acl`) has a :class:`Limit`: a token bucket of
samples per second with a burst (the classic policer: RFC 2697's single-rate meter, one colour:
conforming or dropped) and a largest sample size. A :class:`Budget` keeps one bucket per *source*,
the concrete key a sample arrived on: ``uav/<id>/state`` can only be written by ``uav<id>`` (the
gateway's access control), so the key names its sender. Excess samples are dropped before they are
decoded and counted by the subscriber (:class:`protocol.bus.Counters`, kind ``budget-rate`` or
``budget-size``): a flood from one source costs the receiver a dictionary look-up per sample and
never delays or evicts another source's traffic.

The limits (:data:`LIMITS`, per topic of :mod:`protocol.keys`) sit well above what the system
sends (README, "Choices where the paper is silent"):

==========  ==================  =========  ==========  =============================================
topic       sent                rate /s    burst       largest sample
==========  ==================  =========  ==========  =============================================
state       20 Hz per UAV       60         60          16 KiB (a state is ~0.5 KB)
event       a few per mission   20         50          16 KiB (text is capped at 4 KiB)
heartbeat   2 Hz                20         20          4 KiB
camera      1 per capture point 20         96          4 MiB (a 640x480 JPEG is ~50 KB; recovery
                                                       replays a camera's 32-frame cache at once)
preview     2 Hz                10         10          512 KiB
defects     1 per frame         40         200         1 MiB (up to 10,000 defects)
stats       1 Hz per service    10         20          256 KiB
==========  ==================  =========  ==========  =============================================

A source that keeps inside its budget is never dropped; one that floods is cut to the budget's
rate. The rate is charged to well-formed samples only (garbage on a key must not use up the budget of
the node that really writes it); garbage has a bucket of its own per source, with the same rate and
burst (:meth:`Budget.admit_undecoded`, :meth:`Budget.charge_garbage`): a source that sent more
undecodable samples than its budget allows has its samples dropped *before decoding* (``budget-garbage``)
until that bucket refills, and a source whose rate is used up is dropped before decoding too: a flood,
well-formed or not, costs the receiver a look-up per sample, not a msgpack parse and a validation
(bench/flood.py, README "Hostile input"). At most :data:`MAX_SOURCES` sources get a bucket of their own; further ones share one
(``(other)``), so a flood of made-up keys cannot grow the table.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

#: sources with a bucket of their own per budget; the rest share the ``(other)`` bucket
MAX_SOURCES = 512
OTHER = "(other)"


@dataclass(frozen=True)
class Limit:
    """Samples per second (sustained), burst (bucket size, samples) and the largest sample, bytes."""

    rate_hz: float
    burst: int
    max_bytes: int

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0 and self.burst >= 1 and self.max_bytes >= 1):
            raise ValueError(f"bad limit {self}")


KIB, MIB = 1024, 1024 * 1024
LIMITS: dict[str, Limit] = {
    "state": Limit(60.0, 60, 16 * KIB),
    "event": Limit(20.0, 50, 16 * KIB),
    "heartbeat": Limit(20.0, 20, 4 * KIB),
    "camera": Limit(20.0, 96, 4 * MIB),
    "preview": Limit(10.0, 10, 512 * KIB),
    "defects": Limit(40.0, 200, 1 * MIB),
    "stats": Limit(10.0, 20, 256 * KIB),
}


@dataclass
class TokenBucket:
    """``rate`` tokens a second up to ``burst``; a sample takes one (RFC 2697, committed rate and burst)."""

    rate: float
    burst: float
    tokens: float = -1.0
    last: float | None = None

    def take(self, now: float) -> bool:
        if self.last is None:
            self.tokens, self.last = self.burst, now
        elif now > self.last:  # a clock that goes back gives nothing and takes nothing
            self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
            self.last = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False

    def peek(self, now: float) -> float:
        """The tokens there would be at ``now`` (nothing taken)."""
        if self.last is None:
            return self.burst
        return min(self.burst, self.tokens + max(0.0, now - self.last) * self.rate)


@dataclass
class Budget:
    """One :class:`Limit` applied per source. Not thread-safe by itself: the bus calls it under its lock."""

    limit: Limit
    max_sources: int = MAX_SOURCES
    _buckets: dict[str, TokenBucket] = field(default_factory=dict)
    _garbage: dict[str, TokenBucket] = field(default_factory=dict)  # per source: undecodable samples
    dropped: Counter[tuple[str, str]] = field(default_factory=Counter)  # (source, reason) -> samples

    def admit(self, source: str, nbytes: int, now: float) -> str | None:
        """None when the sample may go on; else why not: ``budget-size`` or ``budget-rate``."""
        if source not in self._buckets and len(self._buckets) >= self.max_sources:
            source = OTHER
        if nbytes > self.limit.max_bytes:
            reason = "budget-size"
        else:
            bucket = self._buckets.get(source)
            if bucket is None:
                bucket = self._buckets[source] = TokenBucket(self.limit.rate_hz, float(self.limit.burst))
            if bucket.take(now):
                return None
            reason = "budget-rate"
        self.dropped[(source, reason)] += 1
        return reason

    def admit_size(self, source: str, nbytes: int) -> str | None:
        """The size check alone (before decoding): None or ``budget-size``."""
        if nbytes > self.limit.max_bytes:
            self.dropped[(source if source in self._buckets else OTHER, "budget-size")] += 1
            return "budget-size"
        return None

    def _source(self, table: dict[str, Any], source: str) -> str:
        return source if source in table or len(table) < self.max_sources else OTHER

    def admit_undecoded(self, source: str, nbytes: int, now: float) -> str | None:
        """Everything that can be told before decoding: ``budget-size``; ``budget-rate`` while the source's
        bucket is empty (its well-formed samples used up its rate: decoding this one would not change that);
        ``budget-garbage`` while its garbage bucket is empty (more undecodable samples than its rate and
        burst)."""
        if nbytes > self.limit.max_bytes:
            return self.admit_size(source, nbytes)
        src = self._source(self._buckets, source)
        bucket = self._buckets.get(src)
        if bucket is not None and bucket.peek(now) < 1.0:  # its rate is used up: :meth:`admit_rate` would refuse
            self.dropped[(src, "budget-rate")] += 1
            return "budget-rate"
        src = self._source(self._garbage, source)
        bucket = self._garbage.get(src)
        if bucket is None or bucket.peek(now) >= 1.0:
            return None
        self.dropped[(src, "budget-garbage")] += 1
        return "budget-garbage"

    def charge_garbage(self, source: str, now: float) -> None:
        """A sample of ``source`` did not decode: it takes a token of the source's garbage bucket."""
        src = self._source(self._garbage, source)
        bucket = self._garbage.get(src)
        if bucket is None:
            bucket = self._garbage[src] = TokenBucket(self.limit.rate_hz, float(self.limit.burst))
        bucket.take(now)

    def admit_rate(self, source: str, now: float) -> str | None:
        """The rate check alone (after a sample proved well-formed): None or ``budget-rate``."""
        return self.admit(source, 0, now)

    def sources(self) -> int:
        return len(self._buckets)


def for_topic(topic: str) -> Budget:
    """A fresh budget with the limit of a key-space topic (``state``, ``camera``, ...)."""
    return Budget(LIMITS[topic])
