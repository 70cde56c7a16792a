"""Sharing the fleet's cameras between detector instances by key partition. Pure: no bus code.

Design notes: docs/detector.md (services/detector/partition.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from protocol import keys

MAX_UAV = 255


@dataclass(frozen=True)
class Partition:
    index: int = 0
    count: int = 1

    def __post_init__(self) -> None:
        if not (isinstance(self.count, int) and 1 <= self.count <= MAX_UAV):
            raise ValueError(f"partition count must be in 1..{MAX_UAV}, got {self.count!r}")
        if not (isinstance(self.index, int) and 0 <= self.index < self.count):
            raise ValueError(f"partition index must be in 0..{self.count - 1}, got {self.index!r}")

    @classmethod
    def parse(cls, text: str) -> Partition:
        """``"K/N"``, e.g. ``"1/2"``; raises ValueError saying what is wrong."""
        k, sep, n = str(text).strip().partition("/")
        if not sep or not k.strip().isdigit() or not n.strip().isdigit():
            raise ValueError(f"partition must be K/N with 0 <= K < N (e.g. 0/2), got {text!r}")
        return cls(int(k), int(n))

    @property
    def whole(self) -> bool:
        return self.count == 1

    def owns(self, uav: int) -> bool:
        return uav % self.count == self.index

    def uavs(self, max_uav: int = MAX_UAV) -> list[int]:
        """The UAV ids in 1..max_uav this instance owns."""
        if not 1 <= max_uav <= MAX_UAV:
            raise ValueError(f"max UAV id must be in 1..{MAX_UAV}, got {max_uav}")
        return [u for u in range(1, max_uav + 1) if self.owns(u)]

    def camera_keys(self, fleet: str, max_uav: int = MAX_UAV) -> list[str]:
        """The key expressions to subscribe to: the wildcard for the whole fleet, else one key per owned UAV."""
        if self.whole:
            return [keys.camera(fleet, "*")]
        return [keys.camera(fleet, u) for u in self.uavs(max_uav)]

    @property
    def name(self) -> str:
        """The instance's service name (liveliness token, statistics, ``LinkStats.source``)."""
        return "detector" if self.whole else f"detector-{self.index}"

    def __str__(self) -> str:
        return f"{self.index}/{self.count}"
