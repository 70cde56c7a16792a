"""Per-source rate and size budgets on what a subscriber accepts.

Design notes: docs/security.md (protocol/budget.py).
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
