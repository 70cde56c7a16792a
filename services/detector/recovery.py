"""Which imagery frames reached the detector only through recovery (pure: no bus code).

Design notes: docs/detector.md (services/detector/recovery.py).
"""

from __future__ import annotations

from collections import Counter, OrderedDict

__all__ = ["RecoveryTracker"]


class RecoveryTracker:
    """Counts frames delivered by recovery, per SSRC; see docs/detector.md.

    A frame not seen live is declared recovered ``settle_s`` (> 0) after its delivery; ``memory`` live
    sightings are remembered (oldest forgotten first), far more than the frames a recovery can hold back.

    >>> tr = RecoveryTracker(settle_s=1.0)
    >>> tr.live(7, 1, 0.0); tr.delivered(7, 1, 0.0)      # came the first time
    >>> tr.delivered(7, 2, 0.5)                           # lost live, recovered from the cache
    >>> tr.settle(2.0)
    1
    >>> tr.recovered[7]
    1
    """

    def __init__(self, settle_s: float = 1.0, memory: int = 8192) -> None:
        if not settle_s > 0:
            raise ValueError(f"settle_s must be > 0, got {settle_s!r}")
        if isinstance(memory, bool) or not isinstance(memory, int) or memory < 1:
            raise ValueError(f"memory must be an int >= 1, got {memory!r}")
        self.settle_s, self.memory = float(settle_s), memory
        self._live: OrderedDict[tuple[int, int], float] = OrderedDict()
        self._pending: OrderedDict[tuple[int, int], float] = OrderedDict()
        self.recovered: Counter[int] = Counter()

    def live(self, ssrc: int, seq: int, now: float) -> None:
        key = (ssrc, seq & 0xFFFF)
        if self._pending.pop(key, None) is not None:
            return  # the live copy came after all: an ordinary frame
        self._live[key] = now
        self._live.move_to_end(key)
        while len(self._live) > self.memory:
            self._live.popitem(last=False)

    def delivered(self, ssrc: int, seq: int, now: float) -> None:
        key = (ssrc, seq & 0xFFFF)
        if self._live.pop(key, None) is None:
            self._pending[key] = now

    def settle(self, now: float) -> int:
        """Declare recovered the pending frames older than ``settle_s``; returns how many."""
        n = 0
        while self._pending:
            key, t = next(iter(self._pending.items()))
            if now - t < self.settle_s:
                break
            del self._pending[key]
            self.recovered[key[0]] += 1
            n += 1
        return n

    @property
    def pending(self) -> int:
        return len(self._pending)
