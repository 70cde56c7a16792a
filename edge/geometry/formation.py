"""Formation geometry of the UAV triangle: frames, offsets, errors and on-board keeping.

Design notes: docs/edge.md (edge/geometry/formation.py).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.checks import finite_array, finite_vec3, xyz

__all__ = ["DEFAULT_OFFSETS", "offsets_for", "home_offsets", "MAX_ALONG_M", "ROW_PITCH_M", "MAX_CORRECTION_M",
           "rotation_of", "errors_in_formation", "errors_to_inertial", "uav_positions", "centroid_of", "headings",
           "neighbour_correction", "formation_error", "HEADING_MIN_SPEED", "HEADING_WINDOW_S", "ShapeErrorMeter",
           "tracking_error"]

#: Desired offsets ΔT_n of UAVs 1, 2, 3 in the formation frame, metres (P9); row n-1 is UAV n.
DEFAULT_OFFSETS: NDArray[np.float64] = np.array([[0.0, 0.0, 2.0], [3.0, 0.0, -1.0], [-3.0, 0.0, -1.0]], dtype=float)
DEFAULT_OFFSETS.setflags(write=False)

#: Default bound on the on-board formation correction, metres (our choice; the paper is silent).
MAX_CORRECTION_M = 3.0


#: Along-track half-length of the fleet, m: :func:`offsets_for` adds rows below instead of
#: lengthening the line past it (the monorail start is 8 m from the box's side).
MAX_ALONG_M = 6.0
#: Pitch of the fleet's slots along travel (and of the two imaging rows in height), m.
PITCH_M = 3.0
#: Height pitch of the rows stacked under the two imaging rows, m (2.5: every pair stays above the
#: scenario's 2 m minimum separation and 48 UAVs fit the monorail's altitude band at the wall).
ROW_PITCH_M = 2.5


def offsets_for(n: int) -> NDArray[np.float64]:
    """Offsets ΔT_n for a fleet of ``n`` UAVs (P9), row n-1 UAV n: the paper's triangle, then the slots of
    docs/edge.md (edge/geometry/formation.py, "Fleet slots")."""
    if not isinstance(n, (int, np.integer)) or not 1 <= n <= 255:
        raise ValueError(f"formation size must be an int in 1..255, got {n!r}")
    cols = [0.0]
    for k in range(1, int(MAX_ALONG_M // PITCH_M) + 1):
        cols += [PITCH_M * k, -PITCH_M * k]
    rows = [xyz(o) for o in DEFAULT_OFFSETS]
    for c in cols[1:]:  # fill the two imaging rows outward: ahead/behind on the top row, then the lower
        if c > 0:
            rows += [(c, 0.0, 2.0), (-c, 0.0, 2.0)]
            if c + PITCH_M <= MAX_ALONG_M:
                rows += [(c + PITCH_M, 0.0, -1.0), (-c - PITCH_M, 0.0, -1.0)]
    rows.append((0.0, 0.0, -1.0))
    z = -1.0
    while len(rows) < n:
        z -= ROW_PITCH_M
        rows += [(x, 0.0, z) for x in cols]
    return np.array(rows[:n], dtype=float)


def home_offsets(offsets: ArrayLike) -> NDArray[np.float64]:
    """Launch points ``(k, 2)`` in the formation frame (x along travel, y left), m: under each slot, or
    :data:`PITCH_M` further left per earlier UAV launching from the same spot."""
    off = np.asarray(offsets, float).reshape(-1, 3)
    seen: dict[float, int] = {}
    out = np.zeros((off.shape[0], 2))
    for i, (x, y, _) in enumerate(off):
        key = round(float(x), 3)
        k = seen.get(key, 0)
        seen[key] = k + 1
        out[i] = (x, y + PITCH_M * k)
    return out


def rotation_of(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> NDArray[np.float64]:
    """Rotation ``R_OF = Rz(ψ) Ry(θ) Rx(φ)`` from the formation frame to the inertial frame (P7); angles in
    radians, broadcast: ``(3, 3)`` for scalars, ``(N, 3, 3)`` for N angles.

    >>> R = rotation_of(0.0, 0.0, np.pi / 2)
    >>> np.round(R @ [1.0, 0.0, 0.0], 12)
    array([0., 1., 0.])
    """
    phi, theta, psi = np.broadcast_arrays(finite_array("roll", roll), finite_array("pitch", pitch),
                                          finite_array("yaw", yaw))
    cf, sf = np.cos(phi), np.sin(phi)
    ct, st = np.cos(theta), np.sin(theta)
    cp, sp = np.cos(psi), np.sin(psi)
    R = np.empty(phi.shape + (3, 3))
    R[..., 0, 0] = cp * ct
    R[..., 0, 1] = cp * st * sf - sp * cf
    R[..., 0, 2] = cp * st * cf + sp * sf
    R[..., 1, 0] = sp * ct
    R[..., 1, 1] = sp * st * sf + cp * cf
    R[..., 1, 2] = sp * st * cf - cp * sf
    R[..., 2, 0] = -st
    R[..., 2, 1] = ct * sf
    R[..., 2, 2] = ct * cf
    return R


def errors_in_formation(desired: ArrayLike, actual: ArrayLike, R_OF: ArrayLike) -> NDArray[np.float64]:
    """Position errors ``e^F = R_OF^T (P_d − P)`` (P8), ``(..., 3)``, with ``R_OF`` ``(3, 3)`` or ``(..., 3, 3)``."""
    d = finite_array("desired", desired)
    a = finite_array("actual", actual)
    R = finite_array("R_OF", R_OF)
    if d.shape[-1:] != (3,) or a.shape[-1:] != (3,) or R.shape[-2:] != (3, 3):
        raise ValueError("positions must end in axis 3 and R_OF in (3, 3)")
    e = d - a
    return np.einsum("...ji,...j->...i", R, e)


def errors_to_inertial(e_F: ArrayLike, R_OF: ArrayLike) -> NDArray[np.float64]:
    """Inverse of :func:`errors_in_formation`: ``e = R_OF e^F`` (P8)."""
    e = finite_array("e_F", e_F)
    R = finite_array("R_OF", R_OF)
    if e.shape[-1:] != (3,) or R.shape[-2:] != (3, 3):
        raise ValueError("e_F must end in axis 3 and R_OF in (3, 3)")
    return np.einsum("...ij,...j->...i", R, e)


def uav_positions(centroid: ArrayLike, yaw: ArrayLike, offsets: ArrayLike = DEFAULT_OFFSETS, roll: ArrayLike = 0.0,
                  pitch: ArrayLike = 0.0) -> NDArray[np.float64]:
    """Slots ``(N, M, 3)`` of M UAVs along a centroid path ``(N, 3)``, ``P_n = P_F + R_OF ΔT_n`` (P9); ``yaw``,
    ``roll`` and ``pitch`` scalars or ``(N,)``."""
    c = np.atleast_2d(finite_array("centroid", centroid))
    if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] == 0:
        raise ValueError(f"centroid must have shape (N, 3) with N >= 1, got {c.shape}")
    off = np.atleast_2d(finite_array("offsets", offsets))
    if off.ndim != 2 or off.shape[1] != 3 or off.shape[0] == 0:
        raise ValueError(f"offsets must have shape (M, 3) with M >= 1, got {off.shape}")
    n = c.shape[0]
    try:
        angles = np.broadcast_arrays(*(np.broadcast_to(np.asarray(a, float), (n,)) for a in (roll, pitch, yaw)))
    except ValueError:
        raise ValueError(f"roll, pitch and yaw must be scalars or have shape ({n},)") from None
    R = rotation_of(*angles)  # (N, 3, 3)
    return c[:, None, :] + np.einsum("nij,mj->nmi", R, off)


def centroid_of(positions: ArrayLike) -> NDArray[np.float64]:
    """Formation centroid ``P_F = (1/M) Σ P_n`` (P6) of positions ``(M, 3)``."""
    p = np.atleast_2d(finite_array("positions", positions))
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise ValueError(f"positions must have shape (M, 3) with M >= 1, got {p.shape}")
    return p.mean(axis=0)


def headings(path: ArrayLike) -> NDArray[np.float64]:
    """Heading ψ ``(N,)`` of a path ``(N, 3)`` from its central-difference tangent (:func:`numpy.gradient`);
    points without horizontal motion take the nearest earlier (else later) heading, 0 if none."""
    p = finite_array("path", path)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise ValueError(f"path must have shape (N, 3) with N >= 1, got {p.shape}")
    n = p.shape[0]
    if n == 1:
        return np.zeros(1)
    d = np.gradient(p[:, :2], axis=0)
    norm = np.hypot(d[:, 0], d[:, 1])
    scale = max(float(np.max(np.abs(p[:, :2]))), 1.0)
    valid = norm > 1e-9 * scale
    if not np.any(valid):
        return np.zeros(n)
    idx = np.where(valid, np.arange(n), -1)
    idx = np.maximum.accumulate(idx)  # last valid index at or before i
    first = int(np.argmax(valid))
    idx[idx < 0] = first
    return np.arctan2(d[idx, 1], d[idx, 0])


def _offset_of(offsets: Mapping[int, ArrayLike], uav: int) -> NDArray[np.float64]:
    if uav not in offsets:
        raise ValueError(f"no formation offset for UAV {uav}")
    return finite_vec3(f"offset of UAV {uav}", offsets[uav])


def neighbour_correction(own_tau: float, own_ref_vel: ArrayLike,
                         neighbours: Mapping[int, tuple[ArrayLike, ArrayLike, float, float]],
                         stale_after_s: float = 1.0, gain: float = 0.8, max_correction: float = MAX_CORRECTION_M,
                         clock_rate: float = 1.0) -> NDArray[np.float64]:
    """Own reference correction from the neighbours' shared states (P8), zeros without a fresh neighbour.

    ``neighbours`` maps an id to (position, planned position, trajectory time τ_j, age s); the error of
    neighbour j is ``(P_j − P_j,d) − v_d (τ − τ_j − age_j clock_rate)``, the correction ``gain`` times their
    mean, bounded in norm by ``max_correction``. The derivation is in docs/edge.md
    (edge/geometry/formation.py, "Formation keeping").
    """
    if not math.isfinite(own_tau):
        raise ValueError("own_tau must be finite")
    v = finite_vec3("own_ref_vel", own_ref_vel)
    if not (math.isfinite(stale_after_s) and stale_after_s >= 0.0):
        raise ValueError("stale_after_s must be finite and >= 0")
    if not (0.0 <= gain <= 1.0):
        raise ValueError("gain must be in [0, 1]")
    if not (math.isfinite(max_correction) and max_correction >= 0.0):
        raise ValueError("max_correction must be finite and >= 0")
    if not (math.isfinite(clock_rate) and clock_rate > 0.0):
        raise ValueError("clock_rate must be finite and > 0")
    errs = []
    for j, (pos, ref, tau_j, age) in neighbours.items():
        age, tau_j = float(age), float(tau_j)
        if math.isnan(age) or not math.isfinite(tau_j):
            raise ValueError(f"age and tau of UAV {j}'s state must be numbers")
        if age > stale_after_s:
            continue
        lead = max(age, 0.0) * clock_rate  # trajectory time the neighbour flew since its state
        errs.append(finite_vec3(f"position of UAV {j}", pos) - finite_vec3(f"plan of UAV {j}", ref)
                    - v * (own_tau - tau_j - lead))
    if not errs:
        return np.zeros(3)
    corr = gain * np.mean(errs, axis=0)
    norm = float(np.linalg.norm(corr))
    if norm > max_correction:
        corr *= max_correction / norm
    return corr


def formation_error(positions: Mapping[int, ArrayLike], centroid: ArrayLike | None, yaw: float,
                    offsets: Mapping[int, ArrayLike]) -> float:
    """RMS shape error (P6)-(P9), metres: ``sqrt(mean_n |(P_n − P̄) − R_OF (ΔT_n − ΔT̄)|²)`` over the UAVs in both
    mappings (translation does not count). One UAV: its distance to ``centroid + R_OF ΔT_n`` (0 without a centroid)."""
    if not math.isfinite(yaw):
        raise ValueError("yaw must be finite")
    ids = sorted(i for i in positions if i in offsets)
    if not ids:
        raise ValueError("no UAV has both a position and an offset")
    P = np.array([finite_vec3(f"position of UAV {i}", positions[i]) for i in ids])
    D = np.array([_offset_of(offsets, i) for i in ids])
    R = rotation_of(0.0, 0.0, yaw)
    if len(ids) == 1:
        if centroid is None:
            return 0.0
        c = finite_vec3("centroid", centroid)
        return float(np.linalg.norm(P[0] - (c + R @ D[0])))
    rel_p = P - P.mean(axis=0)
    rel_d = (D - D.mean(axis=0)) @ R.T
    return float(np.sqrt(np.mean(np.sum((rel_p - rel_d) ** 2, axis=1))))


#: Below this horizontal centroid speed the formation heading is held, m/s.
HEADING_MIN_SPEED = 0.3
#: The centroid velocity giving the formation heading is averaged over this window centred on each time, s.
HEADING_WINDOW_S = 1.0


class ShapeErrorMeter:
    """The formation error (:func:`formation_error`) along a stream of the fleet's positions, with the one
    heading rule that the report, the terminal line and the web page share (docs/edge.md,
    edge/geometry/formation.py, "Heading rule")."""

    def __init__(self, offsets: Mapping[int, ArrayLike], window_s: float = HEADING_WINDOW_S,
                 min_speed: float = HEADING_MIN_SPEED) -> None:
        self.offsets, self.half, self.min_speed = offsets, float(window_s) / 2, float(min_speed)
        self.yaw: float | None = None
        self.first_yaw: float | None = None  # the first heading found
        self.latest: float | None = None  # the newest sample's error known
        self._t0 = math.nan  # the first sample's time (NaN until the first sample)
        self._buf: list[tuple[float, NDArray[np.float64], dict[int, NDArray[np.float64]]]] = []
        self._next = 0  # index in _buf of the first sample not evaluated yet

    def _centroid_at(self, t: float) -> NDArray[np.float64]:
        ts = [x[0] for x in self._buf]
        return np.array([np.interp(t, ts, [x[1][k] for x in self._buf]) for k in range(2)])

    def _evaluate(self, k: int, t_end: float) -> tuple[float, float | None]:
        t, _, pos = self._buf[k]
        a, b = max(t - self.half, self._t0), min(t + self.half, t_end)
        vel = (self._centroid_at(b) - self._centroid_at(a)) / max(b - a, 1e-9)
        if math.hypot(float(vel[0]), float(vel[1])) >= self.min_speed:
            self.yaw = math.atan2(float(vel[1]), float(vel[0]))
            if self.first_yaw is None:
                self.first_yaw = self.yaw
        err = None if self.yaw is None else formation_error(pos, None, self.yaw, self.offsets)
        if err is not None:
            self.latest = err
        return t, err

    def _drain(self, t_end: float, everything: bool) -> list[tuple[float, float | None]]:
        out = []
        while self._next < len(self._buf) and (everything or self._buf[self._next][0] + self.half <= t_end):
            out.append(self._evaluate(self._next, t_end))
            self._next += 1
        # keep what later windows still reach: one sample at or before the next one's window start
        if self._next < len(self._buf):
            start = self._buf[self._next][0] - self.half
            drop = 0
            while drop + 1 < len(self._buf) and self._buf[drop + 1][0] <= start:
                drop += 1
            del self._buf[:drop]
            self._next -= drop
        return out

    def add(self, t: float, positions: Mapping[int, ArrayLike]) -> list[tuple[float, float | None]]:
        """A sample: ``positions`` (by UAV id, at least two with an offset) at time ``t`` (s, increasing).
        Returns the (time, error in metres or None) of the samples whose window it completed, oldest first."""
        ids = [u for u in sorted(positions) if u in self.offsets]
        if len(ids) < 2:
            raise ValueError("the formation error needs at least two UAVs with an offset")
        t = float(t)
        if not math.isfinite(t) or (self._buf and not t > self._buf[-1][0]):
            raise ValueError("sample times must be finite and increase")
        pos = {u: finite_vec3(f"position of UAV {u}", positions[u]) for u in ids}
        if math.isnan(self._t0):
            self._t0 = t
        self._buf.append((t, np.mean([pos[u] for u in ids], axis=0)[:2], pos))
        return self._drain(t, everything=False)

    def flush(self) -> list[tuple[float, float | None]]:
        """The errors of the samples still waiting for later ones (the series ends: windows clipped to it)."""
        return self._drain(self._buf[-1][0], everything=True) if self._buf else []

    @classmethod
    def series(cls, t: ArrayLike, positions: Mapping[int, ArrayLike], offsets: Mapping[int, ArrayLike],
               **rule: float) -> NDArray[np.float64]:
        """The error at each of the times ``t`` (N,) of ``positions`` (by UAV id, (N, 3) each), metres."""
        t = np.asarray(t, dtype=float)
        ids = [u for u in sorted(positions) if u in offsets]
        if t.ndim != 1 or t.size == 0 or len(ids) < 2:
            raise ValueError("need N >= 1 sample times and at least two UAVs with an offset")
        pos = {u: np.asarray(positions[u], dtype=float) for u in ids}
        if any(p.shape != (t.size, 3) for p in pos.values()):
            raise ValueError(f"positions must have shape ({t.size}, 3)")
        meter = cls(offsets, **rule)
        out: list[float | None] = []
        for k in range(t.size):
            out += [e for _, e in meter.add(float(t[k]), {u: pos[u][k] for u in ids})]
        out += [e for _, e in meter.flush()]
        first = 0.0 if meter.first_yaw is None else meter.first_yaw
        return np.array([formation_error({u: pos[u][k] for u in ids}, None, first, offsets) if e is None else e
                         for k, e in enumerate(out)])


def tracking_error(positions: Mapping[int, ArrayLike], refs: Mapping[int, ArrayLike]) -> float | None:
    """RMS distance of each UAV from its own planned position now (its slot, P9), metres; over the UAVs
    present in both mappings, None if none. Not the formation error: a formation that lags its plan as a
    whole keeps its shape (no formation error) and shows here."""
    ids = [u for u in sorted(positions) if u in refs]
    if not ids:
        return None
    d2 = [float(np.sum((finite_vec3(f"position of UAV {u}", positions[u])
                        - finite_vec3(f"plan of UAV {u}", refs[u])) ** 2)) for u in ids]
    return math.sqrt(sum(d2) / len(d2))
