"""The mission report: figures, plots and a Markdown page from a recorded mission.

Pure code (numpy, matplotlib through its object API and the Agg canvas, so it never touches the
global pyplot state or the caller's backend), no bus code. Input: a
:class:`services.gcs.record.MissionRecord`; output (:func:`write_report`) in one folder:

- ``record.json`` -- the record itself, so the report can be re-made;
- ``report.json`` -- every figure computed (:class:`ReportSummary`, ``null`` where undefined);
- ``report.md`` -- the paper's results section (PAPER.md Sections 3-6) re-told from this run,
  with the plots embedded by relative path and tables for the numbers;
- the plots of the paper's results figures: ``trajectories.png`` ("Trajectories of three UAVs
  tracking the planned paths"), ``altitudes.png`` ("Altitudes of the three UAVs in the
  formation test"), ``path_error.png`` ("Errors between the planned and flown paths"),
  ``formation_error.png``, ``convergence.png`` (the planner's best cost per iteration, cf. Table
  I), ``defects_map.png`` (defects found on the surface vs the ground truth) and ``links.png``
  (latency distributions per link class, DESIGN.md "The three link classes").

How the figures are measured (our choices where the paper is silent)
--------------------------------------------------------------------
*Tracking states.* Path and formation figures use the states where a UAV tracks its trajectory:
mode MISSION with a trajectory position (``wp_index >= 0`` or ``progress > 0``); the transit to
the first waypoint and the wait there report ``wp_index = -1`` and are left out. A driver that
never fills those fields (all MISSION states at ``wp_index = -1``, ``progress = 0``) has all its
MISSION states counted.

*Path error* (paper's Fig. "Errors between the planned and flown paths"). Geometric: the
distance from each flown position to the planned polyline (the trajectory's waypoints joined by
segments; the planner samples them densely), which ignores a lag in time. Time-aligned: the
distance to the planned position at the same trajectory time, the plan's time ``τ`` mapped to
the states' simulation time ``t`` by ``t = t_a + (τ − τ_0)``; the anchor ``t_a`` is the first
tracking state's ``t − progress · duration`` (the first MISSION state's ``t`` when progress is
not reported). A pause (hold, resume) therefore shows as a growing time-aligned error.

*Formation error.* The UAVs' positions are linearly interpolated to common times (the union of
their state times inside the window where every UAV tracks), the heading ψ is that of the flown
centroid's horizontal velocity averaged over 1 s (held at its last value while the centroid moves
slower than 0.3 m/s; before the first such time, the first heading found) and :func:`edge.formation.formation_error` gives the RMS shape error (P6)-(P9) at each
time, with the scenario's offsets (``scenario["formation"]["offsets"]``, row n−1 for UAV n) or
:data:`edge.formation.DEFAULT_OFFSETS`. The figures are the RMS over time and the maximum. The
planned trajectories are measured the same way (``plan_rms_m``), since in turns and climbs the
heading of the centroid's motion is not always the one the planner placed the slots with.

*Reached goal*: the last position with the trajectory complete (progress 1, in MISSION or HOLD,
i.e. before the ground station lands the formation) is within 2 m of the last planned waypoint
(the last recorded position when the trajectory never completed).

*Link classes.* Telemetry (UDP in the paper): delivered = distinct sequence numbers received,
sent = the sequence span ``max − min + 1`` per UAV; latency = state age ``rx − stamp``.
Imagery (RTP): delivered/sent = ``received / (received + lost)`` from the detector's latest
jitter-buffer statistics (``uavN.camC.*`` metrics, RFC 3550 loss and interarrival jitter);
latency = capture to report ``stamp_report − stamp_capture``. Defect reports (command class,
reliable): latency = delivery ``rx − stamp_report``. Commands (TCP): delivered/sent = commands
acknowledged ok / commands sent; latency = every answered try's round trip ``ack_s``. Latencies
are reported in milliseconds as p50/p95/p99 (numpy's linear percentile), mean and max.

*Planner convergence*: the first iteration whose best cost is within 0.1 % of the final cost,
as :meth:`services.planner.optimiser.OptResult.convergence_iteration` counts it (Table I).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge.formation import DEFAULT_OFFSETS, formation_error
from protocol.messages import Mode, Trajectory
from services.gcs.clock_align import sim_time_shifts
from services.gcs.record import GOAL_RADIUS_M, MissionRecord
from services.gcs.resilience import fault_figures
from services.gcs.scoring import DefectScore, score_defects, surface_uv

__all__ = [
    "GOAL_RADIUS_M",
    "DEFECT_TOLERANCE_M",
    "PLOTS",
    "LATENCY_NAMES",
    "Latency",
    "UavFigures",
    "FormationFigures",
    "CaptureFigures",
    "LinkFigures",
    "PlannerFigures",
    "ReportSummary",
    "polyline_distance",
    "planned_positions",
    "latency_figures",
    "convergence_iteration",
    "shape_errors",
    "summarise",
    "write_report",
]

#: Tolerance of the defect scoring (:func:`services.gcs.scoring.score_defects`), m.
DEFECT_TOLERANCE_M = 0.3
#: Below this horizontal centroid speed the formation heading is held, m/s.
_HEADING_MIN_SPEED = 0.3
#: The centroid velocity giving the formation heading is averaged over this window, s.
_HEADING_WINDOW_S = 1.0
#: Most points drawn per line (longer series are decimated for plotting only).
_PLOT_POINTS = 4000
#: Link flow -> the name its latency is repeated under in ``report.json``.
LATENCY_NAMES = {"telemetry": "age_ms", "imagery": "capture_to_report_ms", "defect_reports": "delivery_ms",
                 "command": "ack_ms"}
#: The plot files, in the order of the paper's results section.
PLOTS = ("trajectories.png", "altitudes.png", "path_error.png", "formation_error.png", "convergence.png",
         "defects_map.png", "links.png")


# ============================================================================ figures (data)
@dataclass
class Latency:
    """Distribution of one latency, milliseconds; ``None`` when there is no sample."""

    n: int = 0
    p50: float | None = None
    p95: float | None = None
    p99: float | None = None
    mean: float | None = None
    max: float | None = None


@dataclass
class UavFigures:
    """Flight figures of one UAV."""

    uav: int
    states: int = 0
    tracking_states: int = 0
    reached_goal: bool = False
    goal_distance_m: float | None = None
    path_length_m: float = 0.0
    mission_length_m: float = 0.0
    planned_length_m: float | None = None
    path_error_rms_m: float | None = None
    path_error_mean_m: float | None = None
    path_error_max_m: float | None = None
    time_error_rms_m: float | None = None
    time_error_max_m: float | None = None
    time_anchor_s: float | None = None
    captures_planned: int = 0
    captures_imaged: int = 0
    telemetry_received: int = 0
    telemetry_sent: int = 0


@dataclass
class FormationFigures:
    """Formation shape error during the MISSION phase (RMS over time and maximum), metres.

    ``plan_rms_m`` / ``plan_max_m``: the planned trajectories' own shape error measured the same
    way over the plan's waypoint times (the heading from the centroid's motion need not be the
    one the planner placed the slots with, e.g. in turns and climbs).
    """

    rms_m: float | None = None
    max_m: float | None = None
    mean_m: float | None = None
    samples: int = 0
    duration_s: float = 0.0
    plan_rms_m: float | None = None
    plan_max_m: float | None = None
    uavs: list[int] = field(default_factory=list)
    offsets: dict[int, list[float]] = field(default_factory=dict)


@dataclass
class CaptureFigures:
    """Captures planned (waypoints with a capture id) vs imaged (an ``ok`` DefectReport came back)."""

    planned: int = 0
    imaged: int = 0
    ratio: float | None = None
    failed_reports: int = 0
    unplanned_reports: int = 0
    missing: list[tuple[int, int]] = field(default_factory=list)


@dataclass
class LinkFigures:
    """Delivery and latency of one link class (or flow)."""

    name: str
    carried_as: str
    delivered: int = 0
    sent: int = 0
    ratio: float | None = None
    latency_kind: str = ""
    latency_ms: Latency = field(default_factory=Latency)
    per_uav: dict[int, dict[str, float | int | None]] = field(default_factory=dict)


@dataclass
class PlannerFigures:
    algorithm: str
    seed: int
    cost: float
    initial_cost: float | None
    iterations: int
    convergence_iteration: int | None
    planning_time_s: float
    plan_request_s: float
    collision_free: bool
    waypoints: dict[int, int] = field(default_factory=dict)
    duration_s: dict[int, float] = field(default_factory=dict)


@dataclass
class ReportSummary:
    """Every figure of the mission report (written as ``report.json``)."""

    fleet: str
    success: bool
    failures: list[str]
    started: float
    ended: float
    wall_time_s: float | None
    speed: float
    sim_time_s: float | None
    measured_speed: float | None
    planner: PlannerFigures | None
    uavs: dict[int, UavFigures]
    formation: FormationFigures
    captures: CaptureFigures
    defects: DefectScore | None
    links: dict[str, LinkFigures]
    imagery: dict[str, dict[str, float]]
    gateway: dict[str, Any]
    events: list[dict[str, Any]]
    phases: dict[str, float]
    notes: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    faults: dict[str, Any] = field(default_factory=dict)  # services.gcs.resilience.fault_figures

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (non-finite floats become ``None``).

        Besides the fields, for readers that look figures up by what they measure: every link
        repeats its ``latency_ms`` under the latency's own name (:data:`LATENCY_NAMES`, e.g.
        ``links.imagery.capture_to_report_ms``, ``links.telemetry.age_ms``), and ``mission``
        gathers ``sim_duration_s``, ``wall_time_s``, ``speed`` and ``measured_speed``.
        """
        d = _clean(asdict(self))
        for name, link in d["links"].items():
            if name in LATENCY_NAMES:
                link[LATENCY_NAMES[name]] = link["latency_ms"]
        d["mission"] = {"sim_duration_s": d["sim_time_s"], "wall_time_s": d["wall_time_s"], "speed": d["speed"],
                        "measured_speed": d["measured_speed"]}
        return d


def _clean(x: Any) -> Any:
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.generic):
        return _clean(x.item())
    return x


# ============================================================================ pure helpers
def polyline_distance(points: ArrayLike, polyline: ArrayLike) -> NDArray[np.float64]:
    """Distance from each point to the nearest point of a 3-D polyline.

    Parameters
    ----------
    points : array_like, shape (N, 3)
    polyline : array_like, shape (M, 3), M >= 1
        Vertices joined by straight segments (one vertex: a point).

    Returns
    -------
    ndarray, shape (N,)
        ``min_k |p − proj_k(p)|`` over the segments k, the projection clamped to the segment.

    Examples
    --------
    >>> polyline_distance([(1.0, 0.5, 0.0), (3.0, 0.0, 0.0)], [(0, 0, 0), (2, 0, 0)])
    array([0.5, 1. ])
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3) if np.size(points) else np.zeros((0, 3))
    V = np.asarray(polyline, dtype=float)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] == 0:
        raise ValueError(f"polyline must have shape (M, 3) with M >= 1, got {V.shape}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(V))):
        raise ValueError("points and polyline must be finite (got NaN or inf)")
    if V.shape[0] == 1:
        return np.linalg.norm(P - V[0], axis=1)
    A, AB = V[:-1], np.diff(V, axis=0)
    L2 = np.einsum("ij,ij->i", AB, AB)
    L2 = np.where(L2 > 0, L2, 1.0)
    out = np.empty(P.shape[0])
    chunk = max(1, 1_000_000 // A.shape[0])
    for s in range(0, P.shape[0], chunk):
        D = P[s:s + chunk, None, :] - A[None]  # (n, K, 3)
        t = np.clip(np.einsum("nkj,kj->nk", D, AB) / L2, 0.0, 1.0)
        R = D - t[..., None] * AB[None]
        out[s:s + chunk] = np.sqrt(np.min(np.einsum("nkj,nkj->nk", R, R), axis=1))
    return out


def planned_positions(trajectory: Trajectory, tau: ArrayLike) -> NDArray[np.float64]:
    """Planned positions at trajectory times ``tau``: linear between waypoints, clamped at the ends.

    Parameters
    ----------
    trajectory : Trajectory
        A per-UAV trajectory (P9).
    tau : array_like, shape (N,)
        Times on the trajectory's own clock (the waypoints' ``t``), seconds.

    Returns
    -------
    ndarray, shape (N, 3)
    """
    tau = np.asarray(tau, dtype=float).reshape(-1)
    if not np.all(np.isfinite(tau)):
        raise ValueError("tau must be finite")
    t = np.array([w.t for w in trajectory.waypoints])
    W = np.array([w.pos for w in trajectory.waypoints])
    return np.stack([np.interp(tau, t, W[:, k]) for k in range(3)], axis=1)


def latency_figures(values_s: Iterable[float]) -> Latency:
    """p50/p95/p99, mean and max of latencies given in seconds, reported in milliseconds.

    Non-finite values are dropped. Negative values (clock skew between hosts) are kept: they
    are what was measured.
    """
    v = np.asarray(list(values_s), dtype=float) * 1000.0
    v = v[np.isfinite(v)]
    if v.size == 0:
        return Latency()
    p50, p95, p99 = np.percentile(v, [50, 95, 99])
    return Latency(n=int(v.size), p50=float(p50), p95=float(p95), p99=float(p99), mean=float(v.mean()),
                   max=float(v.max()))


def convergence_iteration(history: Sequence[float], rel: float = 1e-3) -> int | None:
    """First iteration whose best cost is within ``rel`` of the final one (Table I's "iterations").

    ``history[0]`` is the initial population's best cost; ``None`` for an empty history.
    """
    h = np.asarray(history, dtype=float)
    if h.size == 0:
        return None
    if not np.all(np.isfinite(h)):
        raise ValueError("convergence history must be finite")
    final = h[-1]
    return int(np.argmax(h <= final + rel * abs(final)))


def _ratio(a: float, b: float) -> float | None:
    return float(a) / float(b) if b else None


def _path_length(P: NDArray[np.float64]) -> float:
    return float(np.sum(np.linalg.norm(np.diff(P, axis=0), axis=1))) if len(P) > 1 else 0.0


# ============================================================================ the record, as arrays
@dataclass
class _Track:
    """One UAV's states as arrays, sorted by simulation time, duplicates (same seq) removed."""

    uav: int
    t: NDArray[np.float64]
    pos: NDArray[np.float64]
    mode: list[Mode]
    seq: NDArray[np.int64]
    stamp: NDArray[np.float64]
    rx: NDArray[np.float64]
    tracking: NDArray[np.bool_]
    progress: NDArray[np.float64]
    anchor: float | None = None  # sim time of trajectory time τ_0

    @property
    def n(self) -> int:
        return int(self.t.size)


def _tracks(record: MissionRecord) -> dict[int, _Track]:
    by_uav: dict[int, list] = {}
    for s in record.states:
        by_uav.setdefault(s.msg.uav, []).append(s)
    out: dict[int, _Track] = {}
    # every UAV's sim time on one clock (edges started apart, without a shared --epoch: issue 14)
    shift = sim_time_shifts({u: ([s.msg.t for s in v], [s.msg.stamp for s in v]) for u, v in by_uav.items()},
                            record.speed) if np.isfinite(record.speed) and record.speed > 0 else {}
    for uav, items in sorted(by_uav.items()):
        seen: dict[int, Any] = {}
        for s in items:
            seen.setdefault(s.msg.seq, s)  # first copy of a duplicated datagram
        items = sorted(seen.values(), key=lambda s: (s.msg.t, s.msg.seq))
        m = [s.msg for s in items]
        mode = [x.mode for x in m]
        mission = np.array([x == Mode.MISSION for x in mode], dtype=bool)
        placed = np.array([x.wp_index >= 0 or x.progress > 0 for x in m], dtype=bool)
        tracking = mission & placed if np.any(mission & placed) else mission
        out[uav] = _Track(
            uav=uav, t=np.array([x.t for x in m]) + shift.get(uav, 0.0),
            pos=np.array([x.pos for x in m], dtype=float).reshape(-1, 3),
            mode=mode, seq=np.array([x.seq for x in m], dtype=np.int64), stamp=np.array([x.stamp for x in m]),
            rx=np.array([s.rx for s in items]), tracking=tracking, progress=np.array([x.progress for x in m]),
        )
    return out


def _trajectories(record: MissionRecord) -> dict[int, Trajectory]:
    return {tr.uav: tr for tr in record.plan.trajectories} if record.plan is not None else {}


def _anchor(track: _Track, traj: Trajectory) -> float | None:
    """Simulation time of the trajectory's first waypoint time (see the module docstring)."""
    idx = np.flatnonzero(track.tracking)
    if idx.size == 0:
        return None
    duration = traj.waypoints[-1].t - traj.waypoints[0].t
    prog = np.flatnonzero(track.tracking & (track.progress > 0))
    if prog.size and duration > 0:
        i = int(prog[0])
        return float(track.t[i] - track.progress[i] * duration)
    first = np.flatnonzero(np.array([m == Mode.MISSION for m in track.mode]))
    return float(track.t[first[0]])


def _offsets(record: MissionRecord, uavs: Iterable[int]) -> dict[int, NDArray[np.float64]]:
    raw = (record.scenario.get("formation") or {}).get("offsets") if isinstance(record.scenario, dict) else None
    if raw is None:
        table = DEFAULT_OFFSETS
    else:
        try:
            table = np.asarray(raw, dtype=float)
        except (TypeError, ValueError):
            table = np.zeros(0)
        if table.ndim != 2 or table.shape[1] != 3 or not np.all(np.isfinite(table)):
            raise ValueError("scenario formation.offsets must be a list of finite [x, y, z] offsets")
    return {u: np.array(table[u - 1]) for u in uavs if 1 <= u <= len(table)}


def _corners(record: MissionRecord) -> list[tuple[float, float, float]]:
    """The inspected surface's corners: the record's, else the scenario's ``surface.corners``."""
    if record.surface_corners:
        return [tuple(map(float, c)) for c in record.surface_corners]
    surf = record.scenario.get("surface") if isinstance(record.scenario, dict) else None
    raw = surf.get("corners") if isinstance(surf, dict) else None
    if not raw:
        return []
    try:
        c = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        c = np.zeros(0)
    if c.shape != (4, 3) or not np.all(np.isfinite(c)):
        raise ValueError("scenario surface.corners must be four finite [x, y, z] points")
    return [tuple(map(float, p)) for p in c]


def _obstacles(record: MissionRecord) -> list[tuple[float, float, float, float]]:
    """``(x, y, radius, height)`` of the scenario's vertical cylinders."""
    out = []
    for i, ob in enumerate(record.scenario.get("obstacles") or []):
        try:
            x, y = (float(c) for c in ob["centre"])
            r, h = float(ob["radius"]), float(ob["height"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"scenario obstacles[{i}] needs centre [x, y], radius and height: {exc}") from None
        if not all(math.isfinite(v) for v in (x, y, r, h)) or r <= 0:
            raise ValueError(f"scenario obstacles[{i}] must be finite with a positive radius")
        out.append((x, y, r, h))
    return out


# ============================================================================ figures
def _uav_figures(uav: int, track: _Track | None, traj: Trajectory | None,
                 imaged: set[tuple[int, int]]) -> tuple[UavFigures, dict[str, NDArray[np.float64]]]:
    f = UavFigures(uav=uav)
    series: dict[str, NDArray[np.float64]] = {}
    if traj is not None:
        W = np.array([w.pos for w in traj.waypoints], dtype=float)
        f.planned_length_m = _path_length(W)
        cids = [w.capture_id for w in traj.waypoints if w.capture_id is not None]
        f.captures_planned = len(cids)
        f.captures_imaged = sum((uav, c) in imaged for c in cids)
    if track is None or track.n == 0:
        return f, series
    f.states = track.n
    f.telemetry_received = int(np.unique(track.seq).size)
    f.telemetry_sent = int(track.seq.max() - track.seq.min() + 1)
    f.path_length_m = _path_length(track.pos)
    tr = track.tracking
    f.tracking_states = int(tr.sum())
    # length over consecutive tracking states only
    both = tr[1:] & tr[:-1]
    f.mission_length_m = float(np.sum(np.linalg.norm(np.diff(track.pos, axis=0), axis=1)[both]))
    if traj is None:
        return f, series
    W = np.array([w.pos for w in traj.waypoints], dtype=float)
    # where the trajectory ended (progress 1, before the ground station lands the formation);
    # the last position when the trajectory never completed
    done = (track.progress >= 1.0) & np.array([m in (Mode.MISSION, Mode.HOLD) for m in track.mode], dtype=bool)
    end = track.pos[done][-1] if done.any() else track.pos[-1]
    f.goal_distance_m = float(np.linalg.norm(end - W[-1]))
    f.reached_goal = f.goal_distance_m <= GOAL_RADIUS_M
    if f.tracking_states == 0:
        return f, series
    P, t = track.pos[tr], track.t[tr]
    geo = polyline_distance(P, W)
    f.path_error_rms_m = float(np.sqrt(np.mean(geo**2)))
    f.path_error_mean_m = float(np.mean(geo))
    f.path_error_max_m = float(np.max(geo))
    track.anchor = _anchor(track, traj)
    series.update(t=t, geometric=geo)
    if track.anchor is not None:
        f.time_anchor_s = track.anchor
        tau = t - track.anchor + traj.waypoints[0].t
        ref = planned_positions(traj, tau)
        te = np.linalg.norm(P - ref, axis=1)
        f.time_error_rms_m = float(np.sqrt(np.mean(te**2)))
        f.time_error_max_m = float(np.max(te))
        series["timed"] = te
    return f, series


def shape_errors(t: ArrayLike, positions: Mapping[int, ArrayLike], offsets: Mapping[int, ArrayLike]
                 ) -> NDArray[np.float64]:
    """Formation shape error at each time, heading from the centroid's own motion, metres.

    Parameters
    ----------
    t : array_like, shape (N,)
        Increasing sample times, s.
    positions : mapping int -> array_like (N, 3)
        Every UAV's position at those times (at least two UAVs with an offset).
    offsets : mapping int -> (3,)
        Formation offsets ΔT_n (P9).

    Returns
    -------
    ndarray, shape (N,)
        :func:`edge.formation.formation_error` (P6)-(P9) at each time, with the heading ψ of the
        centroid's horizontal velocity averaged over 1 s (one-sided at the ends), held at its
        last value while that speed is below 0.3 m/s (before the first faster time: the first
        heading found; never faster: ψ = 0).
    """
    t = np.asarray(t, dtype=float)
    ids = [u for u in sorted(positions) if u in offsets]
    if t.ndim != 1 or t.size == 0 or len(ids) < 2:
        raise ValueError("need N >= 1 sample times and at least two UAVs with an offset")
    pos = {u: np.asarray(positions[u], dtype=float) for u in ids}
    if any(p.shape != (t.size, 3) for p in pos.values()):
        raise ValueError(f"positions must have shape ({t.size}, 3)")
    C = np.mean([pos[u] for u in ids], axis=0)
    # the plain sample-to-sample difference turns position noise into heading noise at low speed
    a = np.clip(t - _HEADING_WINDOW_S / 2, t[0], t[-1])
    b = np.clip(t + _HEADING_WINDOW_S / 2, t[0], t[-1])
    Ca = np.stack([np.interp(a, t, C[:, k]) for k in range(2)], axis=1)
    Cb = np.stack([np.interp(b, t, C[:, k]) for k in range(2)], axis=1)
    vel = (Cb - Ca) / np.maximum(b - a, 1e-9)[:, None]
    valid = np.hypot(vel[:, 0], vel[:, 1]) >= _HEADING_MIN_SPEED
    yaw = np.zeros(t.size)
    if np.any(valid):
        idx = np.maximum.accumulate(np.where(valid, np.arange(t.size), -1))
        idx[idx < 0] = int(np.argmax(valid))
        yaw = np.arctan2(vel[idx, 1], vel[idx, 0])
    return np.array([formation_error({u: pos[u][k] for u in ids}, C[k], float(yaw[k]), offsets)
                     for k in range(t.size)])


def _formation(tracks: Mapping[int, _Track], trajs: Mapping[int, Trajectory],
               offsets: Mapping[int, NDArray[np.float64]]) -> tuple[FormationFigures, dict[str, NDArray[np.float64]]]:
    ids = [u for u in sorted(tracks) if u in offsets and tracks[u].tracking.sum() >= 2]
    out = FormationFigures(uavs=ids, offsets={u: offsets[u].tolist() for u in ids})
    series: dict[str, NDArray[np.float64]] = {}
    # the plan's own shape error, measured the same way (what the flight can at best reproduce)
    planned = [u for u in sorted(trajs) if u in offsets]
    if len(planned) >= 2:
        tau = np.unique(np.concatenate([[w.t for w in trajs[u].waypoints] for u in planned]))
        tau = tau[(tau >= max(trajs[u].waypoints[0].t for u in planned))
                  & (tau <= min(trajs[u].waypoints[-1].t for u in planned))]
        if tau.size:
            pe = shape_errors(tau, {u: planned_positions(trajs[u], tau) for u in planned}, offsets)
            out.plan_rms_m, out.plan_max_m = float(np.sqrt(np.mean(pe**2))), float(np.max(pe))
            anchors = [tracks[u].anchor for u in planned if u in tracks and tracks[u].anchor is not None]
            if anchors:
                series.update(plan_t=tau - trajs[planned[0]].waypoints[0].t + anchors[0], plan_error=pe)
    if len(ids) < 2:
        return out, series
    lo = max(float(tracks[u].t[tracks[u].tracking][0]) for u in ids)
    hi = min(float(tracks[u].t[tracks[u].tracking][-1]) for u in ids)
    if not hi > lo:
        return out, series
    grid = np.unique(np.concatenate([tracks[u].t[(tracks[u].t >= lo) & (tracks[u].t <= hi)] for u in ids]))
    keep = np.ones(grid.size, dtype=bool)
    pos = {}
    for u in ids:
        tk = tracks[u]
        # tracking at a grid time: the latest state at or before it was tracking
        i = np.clip(np.searchsorted(tk.t, grid, side="right") - 1, 0, tk.n - 1)
        keep &= tk.tracking[i]
        pos[u] = np.stack([np.interp(grid, tk.t, tk.pos[:, k]) for k in range(3)], axis=1)
    grid = grid[keep]
    if grid.size < 2:
        return out, series
    err = shape_errors(grid, {u: p[keep] for u, p in pos.items()}, offsets)
    out.rms_m = float(np.sqrt(np.mean(err**2)))
    out.mean_m = float(np.mean(err))
    out.max_m = float(np.max(err))
    out.samples = int(grid.size)
    out.duration_s = float(grid[-1] - grid[0])
    series.update(t=grid, error=err)
    return out, series


def _latest(stats: Sequence[Any]) -> Any | None:
    return max(stats, key=lambda s: (s.msg.stamp, s.rx)).msg if stats else None


def _imagery_metrics(record: MissionRecord) -> dict[str, dict[str, float]]:
    """Latest ``uavN.camC.<name>`` metrics of the detector, grouped by camera."""
    st = _latest(record.detector_stats)
    out: dict[str, dict[str, float]] = {}
    if st is None:
        return out
    for key, value in st.metrics.items():
        parts = key.split(".")
        if len(parts) == 3 and parts[0].startswith("uav") and parts[1].startswith("cam"):
            out.setdefault(f"{parts[0]}.{parts[1]}", {})[parts[2]] = float(value)
    return dict(sorted(out.items()))


def _links(record: MissionRecord, tracks: Mapping[int, _Track], uav_figs: Mapping[int, UavFigures],
           imagery: Mapping[str, Mapping[str, float]]) -> dict[str, LinkFigures]:
    links: dict[str, LinkFigures] = {}
    # telemetry
    tel = LinkFigures("telemetry", "UDP: best-effort, drop", latency_kind="state age rx - stamp")
    for u, f in sorted(uav_figs.items()):
        if f.states:
            tel.per_uav[u] = {"received": f.telemetry_received, "sent": f.telemetry_sent,
                              "ratio": _ratio(f.telemetry_received, f.telemetry_sent)}
            tel.delivered += f.telemetry_received
            tel.sent += f.telemetry_sent
    tel.ratio = _ratio(tel.delivered, tel.sent)
    tel.latency_ms = latency_figures(np.concatenate([tk.rx - tk.stamp for tk in tracks.values()])
                                     if tracks else [])
    links["telemetry"] = tel
    # imagery
    img = LinkFigures("imagery", "RTP: sequenced frames, best-effort",
                      latency_kind="capture to report stamp_report - stamp_capture")
    for cam, m in imagery.items():
        uav = int(cam.split(".")[0][3:]) if cam.split(".")[0][3:].isdigit() else 0
        rec, lost = int(m.get("received", 0)), max(int(m.get("lost", 0)), 0)
        row = img.per_uav.setdefault(uav, {"received": 0, "lost": 0, "jitter_ms": None, "reports": 0, "reports_ok": 0})
        row["received"] = int(row["received"] or 0) + rec
        row["lost"] = int(row["lost"] or 0) + lost
        if "jitter_ms" in m:
            row["jitter_ms"] = max(float(row["jitter_ms"] or 0.0), m["jitter_ms"])
        img.delivered += rec
        img.sent += rec + lost
    for d in record.defects:
        row = img.per_uav.setdefault(d.msg.uav, {"received": 0, "lost": 0, "jitter_ms": None, "reports": 0,
                                                 "reports_ok": 0})
        row["reports"] = int(row["reports"] or 0) + 1
        row["reports_ok"] = int(row["reports_ok"] or 0) + int(d.msg.ok)
    for row in img.per_uav.values():
        row["ratio"] = _ratio(int(row["received"] or 0), int(row["received"] or 0) + int(row["lost"] or 0))
    img.per_uav = dict(sorted(img.per_uav.items()))
    img.ratio = _ratio(img.delivered, img.sent)
    img.latency_ms = latency_figures(d.msg.stamp_report - d.msg.stamp_capture for d in record.defects
                                     if d.msg.ok and d.msg.stamp_capture > 0)
    links["imagery"] = img
    # defect reports back to the ground station
    rep = LinkFigures("defect_reports", "command class: reliable", latency_kind="delivery rx - stamp_report",
                      delivered=len(record.defects))
    rep.latency_ms = latency_figures(d.rx - d.msg.stamp_report for d in record.defects)
    links["defect_reports"] = rep
    # commands
    cmd = LinkFigures("command", "TCP: reliable, block", latency_kind="acknowledgement round trip ack_s",
                      delivered=sum(c.ok for c in record.commands), sent=len(record.commands))
    cmd.ratio = _ratio(cmd.delivered, cmd.sent)
    cmd.latency_ms = latency_figures(a for c in record.commands for a in c.ack_s)
    for c in record.commands:
        row = cmd.per_uav.setdefault(c.uav, {"sent": 0, "ok": 0, "attempts": 0})
        row["sent"] = int(row["sent"] or 0) + 1
        row["ok"] = int(row["ok"] or 0) + int(c.ok)
        row["attempts"] = int(row["attempts"] or 0) + c.attempts
    cmd.per_uav = dict(sorted(cmd.per_uav.items()))
    links["command"] = cmd
    return links


def _captures(record: MissionRecord, trajs: Mapping[int, Trajectory]) -> tuple[CaptureFigures, set[tuple[int, int]]]:
    planned = {(u, w.capture_id) for u, tr in trajs.items() for w in tr.waypoints if w.capture_id is not None}
    ok = {(d.msg.uav, d.msg.capture_id) for d in record.defects if d.msg.ok}
    imaged = planned & ok
    c = CaptureFigures(planned=len(planned), imaged=len(imaged), ratio=_ratio(len(imaged), len(planned)),
                       failed_reports=sum(not d.msg.ok for d in record.defects),
                       unplanned_reports=len(ok - planned), missing=sorted(planned - imaged))
    return c, imaged


def _analyse(record: MissionRecord) -> tuple[ReportSummary, dict[str, Any]]:
    if not isinstance(record, MissionRecord):
        raise ValueError(f"record must be a MissionRecord, got {type(record).__name__}")
    tracks = _tracks(record)
    trajs = _trajectories(record)
    captures, imaged = _captures(record, trajs)
    uavs: dict[int, UavFigures] = {}
    series: dict[str, Any] = {"path": {}}
    for u in sorted(set(tracks) | set(trajs)):
        uavs[u], series["path"][u] = _uav_figures(u, tracks.get(u), trajs.get(u), imaged)
    offsets = _offsets(record, sorted(set(tracks) | set(trajs)))
    formation, series["formation"] = _formation(tracks, trajs, offsets)

    corners = _corners(record)
    notes: list[str] = []
    defects = None
    placed = any(d.msg.ok and any(x.pos is not None for x in d.msg.defects) for d in record.defects)
    if placed and not corners:
        notes.append("defects not scored: the record has no surface corners to place the reported positions on")
    elif record.ground_truth or record.defects:
        defects = score_defects([d.msg for d in record.defects], record.ground_truth, corners, DEFECT_TOLERANCE_M)
    if not record.ground_truth and record.defects:
        notes.append("no ground truth in the record: recall is vacuous and every placed defect counts as false")
    imagery = _imagery_metrics(record)
    links = _links(record, tracks, uavs, imagery)

    planner = None
    if record.plan is not None:
        p = record.plan
        planner = PlannerFigures(
            algorithm=p.algorithm, seed=p.seed, cost=p.cost,
            initial_cost=p.convergence[0] if p.convergence else None, iterations=max(len(p.convergence) - 1, 0),
            convergence_iteration=convergence_iteration(p.convergence), planning_time_s=p.planning_time_s,
            plan_request_s=record.plan_request_s, collision_free=p.collision_free,
            waypoints={tr.uav: len(tr.waypoints) for tr in p.trajectories},
            duration_s={tr.uav: tr.waypoints[-1].t - tr.waypoints[0].t for tr in p.trajectories},
        )
    gw = _latest(record.gateway_stats)
    gateway: dict[str, Any] = {}
    if gw is not None:
        gateway = {"source": gw.source, "uptime_s": gw.uptime_s, "sessions": dict(gw.sessions),
                   "rejected": dict(gw.rejected),
                   "classes": {k: {"samples": v.samples, "bytes": v.bytes} for k, v in gw.classes.items()},
                   "metrics": dict(gw.metrics)}
    events = [{"rx": e.rx, "source": e.msg.source, "stamp": e.msg.stamp, "kind": e.msg.kind,
               "level": e.msg.level.value, "text": e.msg.text, "data": dict(e.msg.data)}
              for e in sorted(record.events, key=lambda e: e.rx)]

    ts = [tk.t for tk in tracks.values() if tk.n]
    sim = float(max(t[-1] for t in ts) - min(t[0] for t in ts)) if ts else None
    st = [tk.stamp for tk in tracks.values() if tk.n]
    wall_states = float(max(s.max() for s in st) - min(s.min() for s in st)) if st else 0.0
    summary = ReportSummary(
        fleet=record.fleet, success=record.success, failures=list(record.failures), started=record.started,
        ended=record.ended, wall_time_s=(record.ended - record.started) if record.ended > 0 else None,
        speed=record.speed, sim_time_s=sim,
        measured_speed=(sim / wall_states) if sim is not None and wall_states > 0 else None,
        planner=planner, uavs=uavs, formation=formation, captures=captures, defects=defects, links=links,
        imagery=imagery, gateway=gateway, events=events, phases=dict(record.phases), notes=notes,
        faults=fault_figures(record),
    )
    series["tracks"], series["trajs"], series["offsets"] = tracks, trajs, offsets
    series["obstacles"] = _obstacles(record)  # validated here, before anything is written
    return summary, series


def summarise(record: MissionRecord) -> ReportSummary:
    """Every figure of the mission report, without writing anything.

    Parameters
    ----------
    record : MissionRecord

    Returns
    -------
    ReportSummary
        See the module docstring for how each figure is measured.

    Raises
    ------
    ValueError
        When ``record`` is not a MissionRecord or its scenario has malformed formation offsets,
        surface corners or obstacles.
    """
    return _analyse(record)[0]


# ============================================================================ plots
def _figure(w: float = 7.0, h: float = 4.5):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=110)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path)


def _thin(n: int) -> slice:
    return slice(None, None, max(1, math.ceil(n / _PLOT_POINTS)))


def _colour(uav: int) -> str:
    return f"C{(uav - 1) % 10}"


def _no_data(ax, text: str = "no data") -> None:
    put = getattr(ax, "text2D", ax.text)  # 3-D axes place screen text with text2D
    put(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="grey")


def _plot_trajectories(record: MissionRecord, series: Mapping[str, Any], path: Path) -> None:
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3d projection)
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = _figure(8.0, 6.5)
    ax = fig.add_subplot(projection="3d")
    tracks, trajs = series["tracks"], series["trajs"]
    pts: list[NDArray[np.float64]] = []
    for u, tr in sorted(trajs.items()):
        W = np.array([w.pos for w in tr.waypoints])
        ax.plot(W[:, 0], W[:, 1], W[:, 2], "--", color=_colour(u), lw=1.0, alpha=0.8, label=f"UAV {u} planned")
        C = np.array([w.pos for w in tr.waypoints if w.capture_id is not None]).reshape(-1, 3)
        if len(C):
            ax.scatter(C[:, 0], C[:, 1], C[:, 2], marker=".", s=8, color=_colour(u), alpha=0.6)
        pts.append(W)
    for u, tk in sorted(tracks.items()):
        s = _thin(tk.n)
        ax.plot(tk.pos[s, 0], tk.pos[s, 1], tk.pos[s, 2], "-", color=_colour(u), lw=1.6, label=f"UAV {u} flown")
        pts.append(tk.pos)
    if record.plan is not None:
        cp = np.array(record.plan.centroid_path)
        ax.plot(cp[:, 0], cp[:, 1], cp[:, 2], ":", color="k", lw=0.8, label="centroid plan")
    start = record.scenario.get("start") or (record.plan.centroid_path[0] if record.plan else None)
    goal = record.scenario.get("goal") or (record.plan.centroid_path[-1] if record.plan else None)
    if start is not None:
        ax.scatter(*np.asarray(start, float), marker="^", s=60, color="green", label="start")
        pts.append(np.asarray(start, float).reshape(1, 3))
    if goal is not None:
        ax.scatter(*np.asarray(goal, float), marker="*", s=90, color="red", label="goal")
        pts.append(np.asarray(goal, float).reshape(1, 3))
    if _corners(record):
        S = np.asarray(_corners(record), float)
        ax.add_collection3d(Poly3DCollection([S], facecolor="tab:orange", edgecolor="darkorange", alpha=0.35))
        pts.append(S)
    if not pts:
        _no_data(ax)
        _save(fig, path)
        return
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0) - 5.0, allp.max(axis=0) + 5.0
    lo[2] = 0.0
    theta = np.linspace(0, 2 * np.pi, 25)
    for x, y, r, h in series["obstacles"]:
        if x + r < lo[0] or x - r > hi[0] or y + r < lo[1] or y - r > hi[1]:
            continue
        X = x + r * np.cos(theta)[None, :].repeat(2, 0)
        Y = y + r * np.sin(theta)[None, :].repeat(2, 0)
        Z = np.array([[0.0], [min(h, hi[2])]]).repeat(theta.size, 1)
        ax.plot_surface(X, Y, Z, color="grey", alpha=0.3, linewidth=0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(np.maximum(hi - lo, 1.0)))
    ax.set_xlabel("x east, m")
    ax.set_ylabel("y north, m")
    ax.set_zlabel("z up, m")
    ax.set_title("Trajectories of the UAVs tracking the planned paths")
    ax.legend(fontsize=7, loc="upper left")
    _save(fig, path)


def _t0(series: Mapping[str, Any]) -> float:
    ts = [tk.t[0] for tk in series["tracks"].values() if tk.n]
    return float(min(ts)) if ts else 0.0


def _plot_altitudes(series: Mapping[str, Any], path: Path) -> None:
    fig = _figure()
    ax = fig.add_subplot()
    t0 = _t0(series)
    drawn = False
    for u, tk in sorted(series["tracks"].items()):
        s = _thin(tk.n)
        ax.plot(tk.t[s] - t0, tk.pos[s, 2], "-", color=_colour(u), label=f"UAV {u} flown")
        tr = series["trajs"].get(u)
        if tr is not None and tk.anchor is not None:
            tw = np.array([w.t for w in tr.waypoints]) - tr.waypoints[0].t + tk.anchor - t0
            ax.plot(tw, [w.pos[2] for w in tr.waypoints], "--", color=_colour(u), lw=1.0, label=f"UAV {u} planned")
        drawn = True
    if not drawn:
        _no_data(ax)
    ax.set_xlabel("time since the first state, s (simulation)")
    ax.set_ylabel("altitude z, m")
    ax.set_title("Altitudes of the UAVs")
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(fontsize=7)
    _save(fig, path)


def _plot_path_error(series: Mapping[str, Any], path: Path) -> None:
    fig = _figure()
    ax = fig.add_subplot()
    t0 = _t0(series)
    drawn = False
    for u, ser in sorted(series["path"].items()):
        if "geometric" not in ser:
            continue
        s = _thin(ser["t"].size)
        ax.plot(ser["t"][s] - t0, ser["geometric"][s], "-", color=_colour(u), label=f"UAV {u} to planned path")
        if "timed" in ser:
            ax.plot(ser["t"][s] - t0, ser["timed"][s], ":", color=_colour(u), label=f"UAV {u} time-aligned")
        drawn = True
    if not drawn:
        _no_data(ax, "no tracking states")
    ax.set_xlabel("time since the first state, s (simulation)")
    ax.set_ylabel("error, m")
    ax.set_title("Errors between the planned and flown paths")
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(fontsize=7)
    _save(fig, path)


def _plot_formation(summary: ReportSummary, series: Mapping[str, Any], path: Path) -> None:
    fig = _figure(7.0, 3.5)
    ax = fig.add_subplot()
    f = series["formation"]
    if "t" in f:
        s = _thin(f["t"].size)
        ax.plot(f["t"][s] - _t0(series), f["error"][s], "-", color="k", label="flown")
        if "plan_t" in f:
            s = _thin(f["plan_t"].size)
            ax.plot(f["plan_t"][s] - _t0(series), f["plan_error"][s], "--", color="C0", lw=0.9,
                    label=f"planned (RMS {summary.formation.plan_rms_m:.2f} m)")
        ax.axhline(summary.formation.rms_m, color="C3", ls=":", lw=0.8, label=f"flown RMS {summary.formation.rms_m:.2f} m")
        ax.legend(fontsize=8)
    else:
        _no_data(ax, "fewer than two UAVs tracking together")
    ax.set_xlabel("time since the first state, s (simulation)")
    ax.set_ylabel("formation RMS shape error, m")
    ax.set_title("Formation error during the mission")
    ax.grid(alpha=0.3)
    _save(fig, path)


def _plot_convergence(record: MissionRecord, summary: ReportSummary, path: Path) -> None:
    fig = _figure(6.0, 3.8)
    ax = fig.add_subplot()
    p = record.plan
    if p is not None and p.convergence:
        ax.plot(np.arange(len(p.convergence)), p.convergence, "-", color="C0", label=p.algorithm)
        k = summary.planner.convergence_iteration if summary.planner else None
        if k is not None:
            ax.axvline(k, color="grey", ls=":", lw=0.8, label=f"converged at {k}")
        ax.legend(fontsize=8)
    else:
        _no_data(ax, "no convergence history")
    ax.set_xlabel("iteration")
    ax.set_ylabel("best cost J_F (P5)")
    ax.set_title("Planner convergence")
    ax.grid(alpha=0.3)
    _save(fig, path)


def _plot_defects(record: MissionRecord, summary: ReportSummary, path: Path) -> None:
    from matplotlib.patches import Rectangle

    fig = _figure(9.0, 3.8)
    ax = fig.add_subplot()
    score = summary.defects
    corners = _corners(record)
    if corners:
        L = surface_uv(np.asarray(corners, float), corners)
        ax.add_patch(Rectangle((0, 0), L[1, 0], L[3, 1], fill=False, ec="k", lw=1.0))
        ax.set_xlim(min(0.0, L[:, 0].min()) - 1, L[:, 0].max() + 1)
        ax.set_ylim(min(0.0, L[:, 1].min()) - 1, L[:, 1].max() + 1)
    found = set(score.found_ids) if score else set()
    for i, g in enumerate(record.ground_truth):
        u0, v0, u1, v1 = g.bbox_uv
        hit = g.id in found
        ax.add_patch(Rectangle((min(u0, u1), min(v0, v1)), abs(u1 - u0), abs(v1 - v0), fill=hit, alpha=0.5 if hit else 1,
                               fc="tab:green", ec="tab:green" if hit else "tab:orange", lw=1.2,
                               label=("crack found" if hit else "crack missed")))
    if score and score.reported_uv:
        fp = {(r, d) for r, d, _, _ in score.false_positives}
        R = np.array([(u, v) for r, d, u, v in score.reported_uv if (r, d) not in fp]).reshape(-1, 2)
        F = np.array([(u, v) for r, d, u, v in score.reported_uv if (r, d) in fp]).reshape(-1, 2)
        if len(R):
            ax.scatter(R[:, 0], R[:, 1], s=12, color="tab:blue", zorder=3, label="reported, on a crack")
        if len(F):
            ax.scatter(F[:, 0], F[:, 1], s=18, marker="x", color="tab:red", zorder=3, label="false positive")
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        uniq = dict(zip(labels, handles))
        ax.legend(uniq.values(), uniq.keys(), fontsize=7, loc="upper right")
    else:
        _no_data(ax, "no ground truth and no reported positions")
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("u along the bottom edge, m")
    ax.set_ylabel("v up the surface, m")
    title = "Defects on the surface"
    if score:
        title += f": recall {score.recall:.2f}, precision {score.precision:.2f} (tolerance {score.tolerance_m:g} m)"
    ax.set_title(title, fontsize=10)
    _save(fig, path)


def _plot_links(record: MissionRecord, series: Mapping[str, Any], path: Path) -> None:
    fig = _figure(7.0, 4.0)
    ax = fig.add_subplot()
    data = {
        "telemetry\nstate age": np.concatenate([tk.rx - tk.stamp for tk in series["tracks"].values()])
        if series["tracks"] else np.zeros(0),
        "imagery\ncapture to report": np.array([d.msg.stamp_report - d.msg.stamp_capture for d in record.defects
                                                if d.msg.ok and d.msg.stamp_capture > 0]),
        "defect report\ndelivery": np.array([d.rx - d.msg.stamp_report for d in record.defects]),
        "command\nack": np.array([a for c in record.commands for a in c.ack_s]),
    }
    data = {k: 1000.0 * v[np.isfinite(v)] for k, v in data.items() if np.size(v)}
    if data:
        ax.boxplot(list(data.values()), whis=(1, 99), showfliers=False)
        ax.set_xticks(range(1, len(data) + 1), list(data.keys()), fontsize=8)
        if min(float(np.min(v)) for v in data.values()) > 0:
            ax.set_yscale("log")
    else:
        _no_data(ax)
    ax.set_ylabel("latency, ms (whiskers p1-p99)")
    ax.set_title("Latency per link class")
    ax.grid(alpha=0.3, axis="y")
    _save(fig, path)


# ============================================================================ markdown
def _fmt(x: Any, nd: int = 2, unit: str = "") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, float):
        return f"{x:.{nd}f}{unit}"
    return f"{x}{unit}"


def _table(head: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _markdown(record: MissionRecord, s: ReportSummary) -> str:
    md: list[str] = [f"# Mission report: fleet `{s.fleet}`", ""]
    outcome = "**success**" if s.success else "**failed**"
    md += [f"Outcome: {outcome}" + (f" ({'; '.join(s.failures)})" if s.failures else "") + ".", ""]
    md += [f"> Note: {n}." for n in s.notes] + ([""] if s.notes else [])
    scen = record.scenario.get("name", "–") if isinstance(record.scenario, dict) else "–"
    md += ["## Experimental setup", "",
           _table(["item", "value"], [
               ["scenario", scen],
               ["UAVs", ", ".join(str(u) for u in s.uavs) or "–"],
               ["mission wall time", _fmt(s.wall_time_s, 1, " s")],
               ["simulation speed factor (set / measured)", f"{_fmt(s.speed)} / {_fmt(s.measured_speed)}"],
               ["simulated time covered by the states", _fmt(s.sim_time_s, 1, " s")],
               ["obstacles", str(len(record.scenario.get("obstacles") or []))],
               ["formation offsets ΔT_n (P9)", "; ".join(f"UAV {u}: {tuple(o)}" for u, o in s.formation.offsets.items())
                or "–"],
           ]), ""]
    md += ["## High-level control results", "", "### Path planning (cf. Table I)", ""]
    p = s.planner
    if p is not None:
        md += [_table(["algorithm", "initial cost", "min cost", "iterations to converge", "iterations",
                       "planning time", "plan request", "collision free"],
                      [[p.algorithm, _fmt(p.initial_cost), _fmt(p.cost), _fmt(p.convergence_iteration), p.iterations,
                        _fmt(p.planning_time_s, 2, " s"), _fmt(p.plan_request_s, 2, " s"), _fmt(p.collision_free)],
                       ["θ-PSO (paper, Table I)", "142.84", "111.02", "68", "300", "–", "–", "–"]]),
               "", "The paper's costs come from its own cost weights and obstacles, so only the shape of the "
               "convergence compares, not the values.", "", "![Planner convergence](convergence.png)", ""]
    else:
        md += ["No plan was received.", ""]
    md += ["### Formation flight", "",
           "![Trajectories of the UAVs tracking the planned paths](trajectories.png)", "",
           "![Altitudes of the UAVs](altitudes.png)", "",
           "![Errors between the planned and flown paths](path_error.png)", "",
           "Path error: distance from each flown position (while tracking) to the planned path; "
           "time-aligned: to the planned position at the same trajectory time.", "",
           _table(["UAV", "reached goal", "distance to goal", "flown (all / tracking)", "planned length",
                   "path error RMS / max", "time-aligned RMS / max", "captures imaged / planned"],
                  [[u, _fmt(f.reached_goal), _fmt(f.goal_distance_m, 2, " m"),
                    f"{_fmt(f.path_length_m, 1)} / {_fmt(f.mission_length_m, 1)} m", _fmt(f.planned_length_m, 1, " m"),
                    f"{_fmt(f.path_error_rms_m)} / {_fmt(f.path_error_max_m)} m",
                    f"{_fmt(f.time_error_rms_m)} / {_fmt(f.time_error_max_m)} m",
                    f"{f.captures_imaged} / {f.captures_planned}"] for u, f in s.uavs.items()]), "",
           "![Formation error](formation_error.png)", "",
           f"Formation shape error over the MISSION phase ({s.formation.samples} samples, "
           f"{_fmt(s.formation.duration_s, 1)} s): RMS {_fmt(s.formation.rms_m)} m, max {_fmt(s.formation.max_m)} m "
           f"(the plan itself, measured the same way: RMS {_fmt(s.formation.plan_rms_m)} m, "
           f"max {_fmt(s.formation.plan_max_m)} m).",
           ""]
    md += ["## Surface inspection results", ""]
    c = s.captures
    md += [f"Captures imaged (a report came back): {c.imaged} of {c.planned} planned"
           + (f" ({100 * c.ratio:.1f} %)" if c.ratio is not None else "")
           + f"; failed reports: {c.failed_reports}; reports for unplanned captures: {c.unplanned_reports}.", ""]
    d = s.defects
    if d is not None and d.n_truth == 0:
        md += [f"No ground truth for this run (real or replayed imagery): {d.n_reported + d.without_pos} defects "
               f"reported, {d.without_pos} of them without a surface position; recall and precision are not "
               "defined.", ""]
    elif d is not None:
        md += [_table(["ground-truth cracks", "found", "reported positions", "on a crack", "without position",
                       "recall", "precision", "F (P20, objects)"],
                      [[d.n_truth, d.n_found, d.n_reported, d.n_true, d.without_pos, _fmt(d.recall), _fmt(d.precision),
                        _fmt(d.f_measure)]]),
               "", f"A reported position counts when it lies within {d.tolerance_m:g} m of a crack's bounding box "
               "on the surface.", ""]
    else:
        md += ["No defect score (no ground truth and no defect reports, or nowhere to place them).", ""]
    md += ["![Defects on the surface](defects_map.png)", ""]
    md += ["## Communication", "",
           _table(["flow", "carried as", "delivered / sent", "ratio", "latency", "p50", "p95", "p99", "n"],
                  [[k, lf.carried_as, f"{lf.delivered} / {lf.sent}" if lf.sent else str(lf.delivered),
                    _fmt(lf.ratio, 4), lf.latency_kind, _fmt(lf.latency_ms.p50, 1, " ms"),
                    _fmt(lf.latency_ms.p95, 1, " ms"), _fmt(lf.latency_ms.p99, 1, " ms"), lf.latency_ms.n]
                   for k, lf in s.links.items()]), ""]
    if s.imagery:
        keys = ["received", "lost", "fraction_lost", "reordered", "late", "duplicated", "jitter_ms"]
        md += ["Imagery per camera (detector jitter buffer, RFC 3550):", "",
               _table(["camera", *keys], [[cam, *(_fmt(m.get(k), 3 if k in ("fraction_lost", "jitter_ms") else 0)
                                                   for k in keys)] for cam, m in s.imagery.items()]), ""]
    md += ["![Latency per link class](links.png)", ""]
    md += _faults_markdown(s.faults)
    md += ["## Events", ""]
    if s.events:
        md += [_table(["rx", "source", "level", "kind", "text"],
                      [[_fmt(e["rx"] - s.started, 2, " s"), e["source"], e["level"], e["kind"],
                        str(e["text"]).replace("|", "/")] for e in s.events]), ""]
    else:
        md += ["No events.", ""]
    if s.gateway.get("rejected"):
        md += ["Gateway rejections: " + ", ".join(f"{k}: {v}" for k, v in s.gateway["rejected"].items()) + ".", ""]
    return "\n".join(md)


def _faults_markdown(f: Mapping[str, Any]) -> list[str]:
    """The "Faults and recovery" section (figures of :func:`services.gcs.resilience.fault_figures`)."""
    md = ["## Faults and recovery", ""]
    if not f:
        return md + ["No record of faults.", ""]
    cmds = f["commands"]
    quiet = not (f["faults"] or f["uavs_lost"] or f["failsafes"] or f["resumes"] or f["gcs_link"] or cmds["failed"]
                 or f["skynet"])
    if quiet:
        return md + [f"No fault injected or seen; {cmds['acknowledged']} of {cmds['sent']} commands acknowledged.", ""]
    md += [f"Times in seconds since the {f['origin']}.", ""]
    if f["faults"]:
        md += ["Faults injected:", "", _table(["t", "action", "target", "as written"],
                                             [[_fmt(x["t_s"], 1, " s"), x["action"], x["target"], x["text"]]
                                              for x in f["faults"]]), ""]
    else:
        md += ["No fault injected.", ""]
    for x in f["seen_again"]:
        line = (f"{x['after'].capitalize()} of {x['target']} at {_fmt(x['t_s'], 1, ' s')} (down since "
                f"{_fmt(x['began_s'], 1, ' s')}): fleet seen again at {_fmt(x['fleet_seen_s'], 2, ' s')}, "
                f"{_fmt(x['fleet_s'], 2, ' s')} after the {x['after']}, {_fmt(x['blackout_s'], 2, ' s')} of blackout "
                "(" + ", ".join(f"UAV {u}: {_fmt(v, 2, ' s')}" for u, v in x["uavs_s"].items()) + ")")
        if x["never"]:
            line += "; never heard again: " + ", ".join(f"UAV {u}" for u in x["never"])
        md += [line + ".", ""]
    if f["gcs_link"]:
        md += ["Ground station's link to the gateway: " + "; ".join(
            f"down at {_fmt(x['down_s'], 1, ' s')}, up at {_fmt(x['up_s'], 1, ' s')}" for x in f["gcs_link"]) + ".", ""]
    if f["uavs_lost"]:
        md += ["UAVs gone from liveliness:", "",
               _table(["UAV", "token gone", "counted lost", "back"],
                      [[x["uav"], _fmt(x["gone_s"], 1, " s"), _fmt(x["lost_s"], 1, " s"), _fmt(x["back_s"], 1, " s")]
                       for x in f["uavs_lost"]]), ""]
    if f["still_lost"]:
        md += ["Lost at the end (not waited for; their capture points not imaged): "
               + ", ".join(f"UAV {u}" for u in f["still_lost"]) + ".", ""]
    if f["failsafes"] or f["resumes"]:
        rows = [(x["t_s"], [x["uav"], "failsafe" + (f": {x['action']}" if x["action"] else ""),
                            f"no heartbeat for {_fmt(x['silent_s'], 1, ' s')}" if x["rx_s"] is not None
                            else "its event was lost with the link; time from its failsafe-cleared event"])
                for x in f["failsafes"]]
        rows += [(x["t_s"], [x["uav"], "resume" if x["ok"] else "resume failed",
                             f"{_fmt(x['after_failsafe_s'], 1, ' s')} after its failsafe"]) for x in f["resumes"]]
        md += ["Failsafes and resumes:", "", _table(["t", "UAV", "what", "detail"],
                                                    [[_fmt(tt, 1, " s"), *r] for tt, r in sorted(rows, key=lambda r: r[0])]),
               ""]
    if f["skynet"]:
        md += ["SkyNet (the boards' view of their neighbours):", "",
               _table(["t", "UAV", "event", "neighbour"],
                      [[_fmt(x["t_s"], 1, " s"), x["uav"], x["kind"], x["neighbour"]] for x in f["skynet"]]), ""]
    rec = f["reception"]
    if rec:
        md += ["State reception at the ground station:", "",
               _table(["UAV", "last heard", "longest gap", "ended at", "gaps > 1 s"],
                      [[u, _fmt(x["last_rx_s"], 1, " s"), _fmt(x["max_gap_s"], 2, " s"), _fmt(x["max_gap_ended_s"], 1, " s"),
                        ", ".join(f"{_fmt(a, 1)}–{_fmt(b, 1)} s" for a, b in x["gaps"]) or "none"]
                       for u, x in rec.items()]), ""]
    md += [f"Commands: {cmds['acknowledged']} of {cmds['sent']} acknowledged"
           + (", every one either acknowledged or listed here as failed:" if cmds["failed"] else "; none failed.")]
    if cmds["failed"]:
        md += ["", _table(["UAV", "command", "id", "acknowledged", "tries", "reason"],
                          [[x["uav"], x["kind"], x["cmd_id"], _fmt(x["acknowledged"]), x["attempts"],
                            str(x["reason"]).replace("|", "/")] for x in cmds["failed"]])]
    return md + [""]


# ============================================================================ entry point
def write_report(record: MissionRecord, folder: str | Path) -> ReportSummary:
    """Write the mission report of ``record`` into ``folder`` (created if needed).

    Files: ``record.json``, ``report.json``, ``report.md`` and the plots :data:`PLOTS` (a plot
    with nothing to show says so on its canvas, so the set of files is always the same).

    Parameters
    ----------
    record : MissionRecord
    folder : str or Path

    Returns
    -------
    ReportSummary
        The figures written to ``report.json``; ``files`` lists the names written.

    Raises
    ------
    ValueError
        See :func:`summarise`; also when ``folder`` exists and is not a directory.
    """
    summary, series = _analyse(record)
    out = Path(folder)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    (out / "record.json").write_text(record.model_dump_json())
    _plot_trajectories(record, series, out / "trajectories.png")
    _plot_altitudes(series, out / "altitudes.png")
    _plot_path_error(series, out / "path_error.png")
    _plot_formation(summary, series, out / "formation_error.png")
    _plot_convergence(record, summary, out / "convergence.png")
    _plot_defects(record, summary, out / "defects_map.png")
    _plot_links(record, series, out / "links.png")
    summary.files = ["record.json", "report.json", "report.md", *PLOTS]
    (out / "report.md").write_text(_markdown(record, summary))
    (out / "report.json").write_text(json.dumps(summary.to_dict(), indent=1, allow_nan=False))
    return summary
