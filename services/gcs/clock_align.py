"""Putting every UAV's simulation time on one clock before the report compares them.

Design notes: docs/report.md (services/gcs/clock_align.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

__all__ = ["estimate_epoch", "sim_time_shifts"]


def estimate_epoch(t: Iterable[float], stamp: Iterable[float], speed: float) -> float | None:
    """The wall-clock epoch (UNIX s) of one UAV's simulation clock from its states' simulation times ``t`` and
    publication times ``stamp`` at ``speed`` (> 0); None when no state tells it."""
    if not (isinstance(speed, (int, float)) and math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be a finite number > 0, got {speed!r}")
    t_a, s_a = np.asarray(list(t), dtype=float), np.asarray(list(stamp), dtype=float)
    if t_a.shape != s_a.shape:
        raise ValueError("t and stamp must have the same length")
    ok = np.isfinite(t_a) & np.isfinite(s_a) & (t_a > 0) & (s_a > 0)
    if not np.any(ok):
        return None
    return float(np.median(s_a[ok] - t_a[ok] / speed))


def sim_time_shifts(tracks: Mapping[int, tuple[Iterable[float], Iterable[float]]], speed: float) -> dict[int, float]:
    """Per UAV, the simulation-time shift (s) that puts its ``t`` on the reference UAV's clock.

    ``tracks`` maps a UAV id to its states' ``(t, stamp)``. The reference is the lowest id whose
    epoch is known; a UAV whose epoch is not known (or every UAV, when none is) gets 0.
    """
    epochs = {u: estimate_epoch(t, s, speed) for u, (t, s) in tracks.items()}
    known = {u: e for u, e in epochs.items() if e is not None}
    if not known:
        return {u: 0.0 for u in tracks}
    ref = known[min(known)]
    return {u: 0.0 if e is None else float((e - ref) * speed) for u, e in epochs.items()}
