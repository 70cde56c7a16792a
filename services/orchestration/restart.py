"""When the launcher restarts a service that exited on its own: exponential back-off, reset after a good run.

Design notes: docs/architecture.md (services/orchestration/restart.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Backoff:
    """Delay before the n-th consecutive restart: ``initial_s * factor**(n-1)``, at most ``max_s``."""

    initial_s: float = 0.5
    factor: float = 2.0
    max_s: float = 30.0
    #: a run at least this long (s) counts as good: the next failure starts the back-off again
    reset_after_s: float = 10.0

    def __post_init__(self) -> None:
        if not (self.initial_s > 0 and self.factor >= 1 and self.max_s >= self.initial_s and self.reset_after_s >= 0):
            raise ValueError(f"bad back-off {self}")

    def delay(self, failures: int) -> float:
        """Seconds to wait before restart number ``failures`` (1-based) of a row of quick failures."""
        if failures < 1:
            raise ValueError("failures counts from 1")
        return min(self.max_s, self.initial_s * self.factor ** min(failures - 1, 64))


@dataclass
class Pending:
    """A restart that is waiting for its time."""

    name: str
    due: float
    failures: int
    code: int | None


@dataclass
class RestartTracker:
    """Which exited services to restart when. Times are any monotonic clock, in seconds."""

    policy: Backoff = field(default_factory=Backoff)
    _failures: dict[str, int] = field(default_factory=dict)
    _pending: dict[str, Pending] = field(default_factory=dict)

    def exited(self, name: str, now: float, ran_s: float, code: int | None) -> Pending:
        """Note that ``name`` ended by itself after running ``ran_s``; its restart, scheduled once."""
        if name in self._pending:
            return self._pending[name]
        failures = 1 if ran_s >= self.policy.reset_after_s else self._failures.get(name, 0) + 1
        self._failures[name] = failures
        p = Pending(name, now + self.policy.delay(failures), failures, code)
        self._pending[name] = p
        return p

    def due(self, now: float) -> list[Pending]:
        """Restarts whose time has come (removed from the pending ones)."""
        out = [p for p in self._pending.values() if p.due <= now]
        for p in out:
            del self._pending[p.name]
        return out

    def pending(self, name: str) -> bool:
        return name in self._pending

    def failures(self, name: str) -> int:
        """Consecutive quick failures of ``name`` so far."""
        return self._failures.get(name, 0)
