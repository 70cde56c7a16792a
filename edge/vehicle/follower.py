"""Trajectory following: time-parametrised waypoints -> reference position, velocity, yaw at time t.

Design notes: docs/edge.md (edge/vehicle/follower.py).
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence
from typing import Literal

import numpy as np

from protocol.messages import Trajectory, Waypoint

__all__ = ["Reference", "Follower"]

Vec3 = tuple[float, float, float]
Reference = tuple[Vec3, Vec3, Vec3, float]  # pos, vel, acc, yaw


class Follower:
    """Interpolates a trajectory ("cubic" by default, or "linear"); keeps track of the capture points already fired."""

    def __init__(self, trajectory: Trajectory | Sequence[Waypoint], interpolation: Literal["cubic", "linear"] = "cubic"):
        wps = list(trajectory.waypoints if isinstance(trajectory, Trajectory) else trajectory)
        if not wps:
            raise ValueError("a trajectory needs at least one waypoint")
        if interpolation not in ("cubic", "linear"):
            raise ValueError("interpolation must be 'cubic' or 'linear'")
        t = np.array([w.t for w in wps], dtype=float)
        P = np.array([w.pos for w in wps], dtype=float)
        yaw = np.unwrap(np.array([w.yaw for w in wps], dtype=float))
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(P)) and np.all(np.isfinite(yaw))):
            raise ValueError("waypoints must be finite")
        if np.any(np.diff(t) <= 0):
            raise ValueError("waypoint times must be strictly increasing")
        self.waypoints = wps
        self.times: list[float] = t.tolist()
        self.t0 = float(t[0])
        self.t_end = float(t[-1])
        self.duration = self.t_end - self.t0
        self.start: Vec3 = tuple(P[0].tolist())
        self.end: Vec3 = tuple(P[-1].tolist())
        self._yaw = yaw.tolist()
        n = len(wps)
        if n > 1:
            dt = np.diff(t)[:, None]
            if interpolation == "cubic":
                V = np.zeros_like(P)
                if n > 2:
                    V[1:-1] = (P[2:] - P[:-2]) / (t[2:] - t[:-2])[:, None]
                dP = P[1:] - P[:-1]
                # Hermite in s = t − t_k: p = a + b s + c s² + d s³
                a, b = P[:-1], V[:-1]
                c = (3 * dP / dt - 2 * V[:-1] - V[1:]) / dt
                d = (-2 * dP / dt + V[:-1] + V[1:]) / dt**2
            else:
                a, b = P[:-1], (P[1:] - P[:-1]) / dt
                c = d = np.zeros_like(a)
            self._coef = [tuple(map(tuple, seg)) for seg in np.stack([a, b, c, d], axis=1).tolist()]
            self._dyaw = (np.diff(yaw) / np.diff(t)).tolist()
        else:
            self._coef = []
            self._dyaw = []
        self._seg = 0
        caps = sorted((w.t, i) for i, w in enumerate(wps) if w.capture_id is not None)
        self._captures = caps
        self._next_capture = 0

    @property
    def captures_fired(self) -> int:
        return self._next_capture

    @property
    def captures_total(self) -> int:
        return len(self._captures)

    def segment(self, t: float) -> int:
        """Index of the last waypoint whose time is <= t (−1 before the first)."""
        if t < self.t0:
            return -1
        return bisect.bisect_right(self.times, t) - 1

    def progress(self, t: float) -> float:
        """Fraction of the trajectory's duration elapsed at t, in [0, 1]."""
        if self.duration <= 0:
            return 1.0 if t >= self.t0 else 0.0
        return min(1.0, max(0.0, (t - self.t0) / self.duration))

    def reference(self, t: float) -> Reference:
        """Reference ``(pos, vel, acc, yaw)`` at trajectory time t (clamped to the ends)."""
        times = self.times
        if t <= self.t0 or not self._coef:
            return self.start, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), self._yaw[0]
        if t >= self.t_end:
            return self.end, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), self._yaw[-1]
        k = self._seg
        if not (times[k] <= t < times[k + 1]):
            if k + 2 < len(times) and times[k + 1] <= t < times[k + 2]:
                k += 1
            else:
                k = bisect.bisect_right(times, t) - 1
            self._seg = k
        s = t - times[k]
        (ax, ay, az), (bx, by, bz), (cx, cy, cz), (dx, dy, dz) = self._coef[k]
        pos = (ax + s * (bx + s * (cx + s * dx)), ay + s * (by + s * (cy + s * dy)), az + s * (bz + s * (cz + s * dz)))
        vel = (bx + s * (2 * cx + 3 * s * dx), by + s * (2 * cy + 3 * s * dy), bz + s * (2 * cz + 3 * s * dz))
        acc = (2 * cx + 6 * s * dx, 2 * cy + 6 * s * dy, 2 * cz + 6 * s * dz)
        yaw = self._yaw[k] + self._dyaw[k] * s
        return pos, vel, acc, yaw

    def due_captures(self, t: float) -> list[Waypoint]:
        """Capture waypoints whose time is <= t and that have not fired yet (each fires once)."""
        caps = self._captures
        i = self._next_capture
        if i >= len(caps) or caps[i][0] > t:
            return []
        out = []
        while i < len(caps) and caps[i][0] <= t:
            out.append(self.waypoints[caps[i][1]])
            i += 1
        self._next_capture = i
        return out
