"""Where a frame's time goes: bounded per-stage duration samples and their percentiles.

Design notes: docs/bus.md (protocol/stages.py).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

__all__ = ["LOG_PREFIX", "StageTimes"]

#: what a log line of stage figures starts with (followed by the owner's name and the summary as JSON)
LOG_PREFIX = "frame path"


class StageTimes:
    """Durations (seconds in, milliseconds out) of named stages, the last ``capacity`` (>= 1) of each; a
    non-finite duration or an empty name is a ValueError, a negative duration (two machines' clocks) is kept."""

    def __init__(self, capacity: int = 1000) -> None:
        if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
            raise ValueError(f"capacity must be an int >= 1, got {capacity!r}")
        self.capacity = capacity
        self._samples: dict[str, deque[float]] = {}

    def add(self, stage: str, seconds: float) -> None:
        if not isinstance(stage, str) or not stage:
            raise ValueError(f"stage must be a non-empty string, got {stage!r}")
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds):
            raise ValueError(f"duration must be a finite number of seconds, got {seconds!r}")
        self._samples.setdefault(stage, deque(maxlen=self.capacity)).append(float(seconds))

    @property
    def stages(self) -> list[str]:
        """Stage names in the order they were first seen."""
        return list(self._samples)

    def summary(self) -> dict[str, dict[str, float]]:
        """Per stage: ``n`` and the ``p50``, ``p95`` and ``max`` milliseconds of its kept samples."""
        out = {}
        for stage, q in self._samples.items():
            ms = 1000.0 * np.asarray(q, dtype=float)
            out[stage] = {"n": int(ms.size), "p50": float(np.percentile(ms, 50)),
                          "p95": float(np.percentile(ms, 95)), "max": float(ms.max())}
        return out

    def metrics(self, prefix: str = "path") -> dict[str, float]:
        """:meth:`summary` flattened for :class:`protocol.messages.LinkStats` metrics:
        ``<prefix>.<stage>.p50_ms``, ``.p95_ms``, ``.max_ms`` and ``.n``."""
        out: dict[str, float] = {}
        for stage, s in self.summary().items():
            out.update({f"{prefix}.{stage}.p50_ms": s["p50"], f"{prefix}.{stage}.p95_ms": s["p95"],
                        f"{prefix}.{stage}.max_ms": s["max"], f"{prefix}.{stage}.n": s["n"]})
        return out
