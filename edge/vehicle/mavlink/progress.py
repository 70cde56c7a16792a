"""Where in the trajectory an autopilot flying the uploaded mission in AUTO is, from what it reports.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/progress.py).
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import NamedTuple

__all__ = ["MissionProgress", "autopilot_window", "bounded"]


class MissionProgress(NamedTuple):
    """The autopilot's mission progress: its current item, its last reached item (−1: none), and the
    trajectory fractions ``[lo, hi]`` they allow."""

    current: int
    reached: int
    lo: float
    hi: float


def autopilot_window(waypoint_seq: Sequence[int], fractions: Sequence[float], reached: int,
                     current: int) -> tuple[float, float]:
    """``(lo, hi)``: the trajectory fraction of the last waypoint whose item was reached (0 before any) and of
    the first waypoint whose item is the current one or later (1 when none is, or ``current`` < 0: unknown).

    ``waypoint_seq[i]`` is the mission item flying trajectory waypoint i (a dropped waypoint shares the item
    of the kept one before it: only the first waypoint of an item counts); ``fractions[i]`` its fraction.
    """
    lo, hi = 0.0, 1.0
    seen: set[int] = set()
    for seq, f in zip(waypoint_seq, fractions):
        if seq in seen:
            continue
        seen.add(seq)
        if seq <= reached:
            lo = max(lo, f)
        if current >= 0 and seq >= current:
            hi = min(hi, f)
    return lo, max(lo, hi)


def bounded(progress: float, window: tuple[float, float], fractions: Sequence[float]) -> tuple[int, float]:
    """``(wp_index, progress)``: the clock's ``progress`` kept inside the autopilot's ``window`` and the last
    waypoint at or before it (as :meth:`edge.vehicle.follower.Follower.segment` counts)."""
    lo, hi = window
    p = min(max(progress, lo), hi)
    return bisect.bisect_right(list(fractions), p + 1e-12) - 1, p
