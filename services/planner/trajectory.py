"""Formation trajectories (P6)-(P9): one time-parametrised trajectory per UAV from the centroid path.

Design notes: docs/planner.md (services/planner/trajectory.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge.geometry.formation import headings, uav_positions
from protocol.messages import CapturePoint, Trajectory, Waypoint

from .cost import clearance, crosses_wall_free
from .scenario import Scenario
from .task import InspectionPass

__all__ = ["FormationTrajectories", "resample", "build_trajectories"]

SIGMA_M = 1.0  # Gaussian smoothing of corners and heading, metres of arc length
BLEND_M = 2.0  # body-yaw blend before/after the pass, metres


@dataclass(frozen=True)
class FormationTrajectories:
    """Result of :func:`build_trajectories`; ``trajectories`` and ``captures`` as wire messages."""

    t: NDArray[np.float64]  # (N,) sample times
    centroid: NDArray[np.float64]  # (N, 3)
    positions: NDArray[np.float64]  # (N, M, 3) UAV slots
    trajectories: list[Trajectory]
    captures: list[CapturePoint]
    min_clearance: float  # least obstacle/wall clearance of any UAV on the densified trajectories (< 0: collision)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1])


def resample(path: ArrayLike, ds: float, extra: ArrayLike = ()) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Arc-length samples of a polyline: every ``ds`` m per segment, vertices, and ``extra`` stations.

    Returns ``(s (N,), points (N, 3))``; uniform samples closer than ``0.25 ds`` to an extra
    station are dropped (the station stays), and duplicates are merged.
    """
    V = np.asarray(path, float)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] < 2 or not np.all(np.isfinite(V)):
        raise ValueError("path must be a finite (N >= 2, 3) polyline")
    if not (np.isfinite(ds) and ds > 0):
        raise ValueError(f"ds must be positive, got {ds!r}")
    seg = np.linalg.norm(np.diff(V, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    uni = [cum[:1]]
    for i, L in enumerate(seg):
        k = max(int(np.ceil(L / ds)), 1)
        uni.append(cum[i] + L * np.arange(1, k + 1) / k)
    s_uni = np.concatenate(uni)
    ext = np.asarray(extra, float).reshape(-1)
    if ext.size:
        if np.any(ext < 0) or np.any(ext > cum[-1]):
            raise ValueError("extra stations must lie on the path")
        near = np.min(np.abs(s_uni[:, None] - ext[None, :]), axis=1) < 0.25 * ds
        near[[0, -1]] = False
        s_uni = s_uni[~near]
    s = np.unique(np.concatenate([s_uni, ext]))
    s = s[np.concatenate([[True], np.diff(s) > 1e-9])]
    pts = np.stack([np.interp(s, cum, V[:, k]) for k in range(3)], axis=1)
    return s, pts


def _gauss_smooth(s: NDArray[np.float64], y: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    w = np.exp(-0.5 * ((s[:, None] - s[None, :]) / sigma) ** 2)
    w /= w.sum(axis=1, keepdims=True)
    return w @ y


def _speed_profile(s, v_nom, kappa, sp) -> NDArray[np.float64]:
    v = np.minimum(v_nom, np.sqrt(sp.lateral_accel / np.maximum(kappa, 1e-9)))
    v[0] = v[-1] = 0.0
    ds = np.diff(s)
    for i in range(1, v.size):  # accelerate
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * sp.accel * ds[i - 1]))
    for i in range(v.size - 2, -1, -1):  # brake
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * sp.accel * ds[i]))
    return v


def build_trajectories(scenario: Scenario, centroid_path: ArrayLike, inspection: InspectionPass | None,
                       ds: float = 1.0) -> FormationTrajectories:
    """Per-UAV trajectories and capture points (P6)-(P9) from a centroid polyline ``(V, 3)`` resampled every
    ``ds`` m; with an ``inspection`` pass the polyline must hold its entry and exit as consecutive vertices
    (ValueError otherwise)."""
    V = np.asarray(centroid_path, float)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] < 2 or not np.all(np.isfinite(V)):
        raise ValueError("centroid_path must be a finite (V >= 2, 3) polyline")
    off = scenario.offsets
    M = off.shape[0]
    seg = np.linalg.norm(np.diff(V, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if inspection is not None:
        hit = np.flatnonzero(
            np.all(np.isclose(V[:-1], inspection.entry, atol=1e-6), axis=1)
            & np.all(np.isclose(V[1:], inspection.exit, atol=1e-6), axis=1)
        )
        if hit.size == 0:
            raise ValueError("centroid_path does not contain the inspection pass (entry -> exit)")
        s_in, s_out = cum[hit[0]], cum[hit[0] + 1]
        stations = s_in + inspection.leg_s
    else:
        s_in = s_out = -np.inf
        stations = np.zeros(0)
    s, C0 = resample(V, ds, np.unique(stations))
    total = s[-1]
    # 2. corner smoothing, pinned ends, exact pass
    fade = np.clip(np.minimum(s, total - s) / (3 * SIGMA_M), 0.0, 1.0)[:, None]
    C = C0 + fade * (_gauss_smooth(s, C0, SIGMA_M) - C0)
    on_pass = (s >= s_in) & (s <= s_out)
    exact = (s >= s_in + 3 * SIGMA_M) & (s <= s_out - 3 * SIGMA_M)
    C[exact] = C0[exact]
    # 3. heading and slots (P7), (P9)
    psi = np.unwrap(headings(C))
    psi = _gauss_smooth(s, psi, SIGMA_M)
    if inspection is not None:
        psi_pass = float(np.arctan2(inspection.direction[1], inspection.direction[0]))
        psi[exact] = psi[exact] + np.angle(np.exp(1j * (psi_pass - psi[exact])))
    P = uav_positions(C, psi, off)  # (N, M, 3)
    # 4. speeds and times
    sp = scenario.speeds
    v_nom = np.where(on_pass, sp.inspect, sp.cruise)
    dpsi = np.abs(np.gradient(psi, s))
    v = _speed_profile(s, v_nom, dpsi, sp)
    dseg = np.diff(s)
    dt = 2.0 * dseg / np.maximum(v[:-1] + v[1:], 1e-6)
    step = np.max(np.linalg.norm(np.diff(P, axis=0), axis=2), axis=1)
    dt = np.maximum(np.maximum(dt, step / sp.max), 1e-3)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    vel = np.linalg.norm(np.diff(P, axis=0), axis=2) / dt[:, None]  # (N-1, M)
    speed = np.zeros((t.size, M))
    speed[1:-1] = 0.5 * (vel[:-1] + vel[1:])
    speed = np.clip(speed, 0.0, sp.max)
    # 5. body yaw: along travel, facing the wall on the pass
    yaw_travel = np.angle(np.exp(1j * psi))
    yaw = np.repeat(yaw_travel[:, None], M, axis=1)
    if inspection is not None:
        look = inspection.look[0]  # every shot looks along the inverse wall normal
        psi_look = float(np.arctan2(look[1], look[0]))
        w = np.clip(np.minimum(s - (s_in - BLEND_M), (s_out + BLEND_M) - s) / BLEND_M, 0.0, 1.0)
        blended = yaw_travel + w * np.angle(np.exp(1j * (psi_look - yaw_travel)))  # along the shorter turn
        yaw = np.angle(np.exp(1j * blended))[:, None].repeat(M, axis=1)
    # captures
    cap_of: dict[tuple[int, int], int] = {}
    captures: list[CapturePoint] = []
    if inspection is not None:
        for cid, (m, leg) in enumerate(zip(inspection.uav, inspection.leg_s)):
            i = int(np.argmin(np.abs(s - (s_in + leg))))
            cap_of[(int(m), i)] = cid
            pos = P[i, m]
            if np.linalg.norm(pos - inspection.positions[cid]) > 0.01:
                raise ValueError(
                    f"capture {cid} of UAV {m + 1} is {np.linalg.norm(pos - inspection.positions[cid]):.3f} m "
                    "off its planned camera position (lead_in too short for the corner smoothing?)"
                )
            captures.append(
                CapturePoint(capture_id=cid, uav=int(m) + 1, pos=tuple(pos.tolist()),
                             look=tuple(inspection.look[cid].tolist()), t=float(t[i]))
            )
    trajs = []
    for m in range(M):
        wps = [
            Waypoint(t=float(t[i]), pos=tuple(P[i, m].tolist()), yaw=float(yaw[i, m]), speed=float(speed[i, m]),
                     capture_id=cap_of.get((m, i)))
            for i in range(t.size)
        ]
        trajs.append(Trajectory(uav=m + 1, waypoints=wps))
    # clearance along the densified UAV polylines
    frac = np.linspace(0.0, 1.0, 5)[:-1]
    dense = P[:-1, None] + frac[None, :, None, None] * np.diff(P, axis=0)[:, None]
    dense = np.concatenate([dense.reshape(-1, M, 3), P[-1:]], axis=0)
    min_cl = float(np.min(clearance(dense, scenario)))
    if not crosses_wall_free(dense, scenario):
        min_cl = min(min_cl, -scenario.cost.uav_radius)
    return FormationTrajectories(t, C, P, trajs, captures, min_cl)
