"""The mission report's figures: a recorded mission in, typed figures out (record -> figures).

Design notes: docs/report.md (services/gcs/figures.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from edge.geometry.formation import DEFAULT_OFFSETS, ShapeErrorMeter
from protocol.checks import xyz
from protocol.messages import Mode, Trajectory
from services.gcs.clock_align import sim_time_shifts
from services.gcs.resilience import fault_figures
from services.gcs.scoring import DefectScore, score_defects
from services.gcs.verdict import GoalCheck, goal_check, imaged_captures, planned_captures
from services.recording.record import GOAL_RADIUS_M, MissionRecord

__all__ = ["GOAL_RADIUS_M", "DEFECT_TOLERANCE_M", "LATENCY_NAMES", "Latency", "UavFigures", "FormationFigures",
           "CaptureFigures", "LinkFigures", "PlannerFigures", "ReportSummary", "Track", "PathSeries", "FormationSeries",
           "LinkSamples", "ReportFigures", "polyline_distance", "planned_positions", "latency_figures",
           "convergence_iteration", "shape_errors", "as_record", "analyse", "summarise"]

#: events listed in report.json and report.md (the record keeps more, the journal all of them)
MAX_REPORT_EVENTS = 500
#: Tolerance of the defect scoring (:func:`services.gcs.scoring.score_defects`), m.
DEFECT_TOLERANCE_M = 0.3
#: Link flow -> the name its latency is repeated under in ``report.json``.
LATENCY_NAMES = {"telemetry": "age_ms", "imagery": "capture_to_report_ms", "defect_reports": "delivery_ms",
                 "command": "ack_ms"}


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
    """Formation shape error during the MISSION phase (RMS over time and maximum), metres; ``plan_rms_m`` /
    ``plan_max_m`` the planned trajectories' own, measured the same way over the plan's waypoint times (the heading
    from the centroid's motion need not be the one the planner placed the slots with, e.g. in turns and climbs)."""

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
    checked: bool = False  # against the capture frames the ground station received itself (MissionRecord.held_captures)


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
    gateway: dict[str, Any]  # the latest statistics of any gateway (one per site: every one in ``gateways``)
    events: list[dict[str, Any]]
    phases: dict[str, float]
    notes: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    faults: dict[str, Any] = field(default_factory=dict)  # services.gcs.resilience.fault_figures
    gateways: dict[str, dict[str, Any]] = field(default_factory=dict)  # source -> its latest statistics

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
    """Distance ``(N,)`` from each point ``(N, 3)`` to the nearest point of a 3-D polyline ``(M, 3)``.

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
    """Planned positions ``(N, 3)`` of a trajectory (P9) at its own times ``tau``: linear between waypoints,
    clamped at the ends."""
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
@dataclass(frozen=True)
class Track:
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

    @property
    def n(self) -> int:
        return int(self.t.size)


@dataclass(frozen=True)
class PathSeries:
    """One UAV's path error over its tracking states (paper's Fig. "Errors between the planned and
    flown paths"): simulation times, geometric error and, when the trajectory time is anchored,
    the time-aligned error (docs/report.md), metres."""

    t: NDArray[np.float64]
    geometric: NDArray[np.float64]
    timed: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class FormationSeries:
    """Formation shape error over time: flown (``t``, ``error``) and planned (``plan_t``,
    ``plan_error``, the plan's times placed on the simulation clock by the first anchor); ``None``
    where not measured."""

    t: NDArray[np.float64] | None = None
    error: NDArray[np.float64] | None = None
    plan_t: NDArray[np.float64] | None = None
    plan_error: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class LinkSamples:
    """The latency samples of each link flow, seconds (the figures' :class:`Latency` and the
    ``links.png`` box plot are both made from these; see docs/report.md)."""

    telemetry: NDArray[np.float64]  # state age rx - stamp
    imagery: NDArray[np.float64]  # capture to report stamp_report - stamp_capture (ok reports)
    defect_reports: NDArray[np.float64]  # delivery rx - stamp_report
    command: NDArray[np.float64]  # every answered try's round trip ack_s


@dataclass(frozen=True)
class ReportFigures:
    """Everything the report is made of, computed once from the record (:func:`analyse`); besides the summary,
    the series the plots draw."""

    summary: ReportSummary  # written as report.json and told in report.md
    tracks: dict[int, Track]
    trajectories: dict[int, Trajectory]
    anchors: dict[int, float]  # UAV that tracked -> sim time of its trajectory's first waypoint (docs/report.md)
    paths: dict[int, PathSeries]
    formation: FormationSeries
    latencies: LinkSamples
    offsets: dict[int, NDArray[np.float64]]
    corners: list[tuple[float, float, float]]
    obstacles: list[tuple[float, float, float, float]]

    @property
    def t0(self) -> float:
        """Simulation time of the first state (the plots' time origin); 0 without states."""
        ts = [tk.t[0] for tk in self.tracks.values() if tk.n]
        return float(min(ts)) if ts else 0.0


def _tracks(record: MissionRecord) -> dict[int, Track]:
    by_uav: dict[int, list] = {}
    for s in record.states:
        by_uav.setdefault(s.msg.uav, []).append(s)
    out: dict[int, Track] = {}
    # every UAV's sim time on one clock (edges started apart, without a shared --epoch)
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
        out[uav] = Track(uav=uav, t=np.array([x.t for x in m]) + shift.get(uav, 0.0),
                         pos=np.array([x.pos for x in m], dtype=float).reshape(-1, 3), mode=mode,
                         seq=np.array([x.seq for x in m], dtype=np.int64), stamp=np.array([x.stamp for x in m]),
                         rx=np.array([s.rx for s in items]), tracking=tracking,
                         progress=np.array([x.progress for x in m]))
    return out


def _anchor(track: Track, traj: Trajectory) -> float | None:
    """Simulation time of the trajectory's first waypoint time (docs/report.md)."""
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


def _corners(record: MissionRecord) -> list[tuple[float, float, float]]:
    """The inspected surface's corners: the record's, else the scenario's ``surface.corners``."""
    if record.surface_corners:
        return [xyz(c) for c in record.surface_corners]
    if record.scenario is None or record.scenario.surface is None:
        return []
    return [xyz(p) for p in record.scenario.surface.corners]


def _obstacles(record: MissionRecord) -> list[tuple[float, float, float, float]]:
    """``(x, y, radius, height)`` of the scenario's vertical cylinders."""
    if record.scenario is None:
        return []
    return [(c.centre[0], c.centre[1], c.radius, c.height) for c in record.scenario.obstacles]


# ============================================================================ figures
def _uav_figures(uav: int, track: Track | None, traj: Trajectory | None, imaged: set[tuple[int, int]],
                 anchor: float | None, goal: GoalCheck | None) -> tuple[UavFigures, PathSeries | None]:
    f = UavFigures(uav=uav)
    series: PathSeries | None = None
    W = None if traj is None else np.array([w.pos for w in traj.waypoints], dtype=float)
    if traj is not None:
        f.planned_length_m = _path_length(W)
        mine = planned_captures([traj])
        f.captures_planned = len(mine)
        f.captures_imaged = len(mine & imaged)
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
    if goal is not None:  # services.gcs.verdict
        f.goal_distance_m = goal.distance_m
        f.reached_goal = goal.reached
    if f.tracking_states == 0:
        return f, series
    P, t = track.pos[tr], track.t[tr]
    geo = polyline_distance(P, W)
    f.path_error_rms_m = float(np.sqrt(np.mean(geo**2)))
    f.path_error_mean_m = float(np.mean(geo))
    f.path_error_max_m = float(np.max(geo))
    te = None
    if anchor is not None:
        f.time_anchor_s = anchor
        tau = t - anchor + traj.waypoints[0].t
        ref = planned_positions(traj, tau)
        te = np.linalg.norm(P - ref, axis=1)
        f.time_error_rms_m = float(np.sqrt(np.mean(te**2)))
        f.time_error_max_m = float(np.max(te))
    return f, PathSeries(t=t, geometric=geo, timed=te)


def shape_errors(t: ArrayLike, positions: Mapping[int, ArrayLike], offsets: Mapping[int, ArrayLike]
                 ) -> NDArray[np.float64]:
    """The formation error at each time (:meth:`edge.geometry.formation.ShapeErrorMeter.series`: the one definition the
    terminal line and the web page use too)."""
    return ShapeErrorMeter.series(t, positions, offsets)


def _formation(tracks: Mapping[int, Track], trajs: Mapping[int, Trajectory], offsets: Mapping[int, NDArray[np.float64]],
               anchors: Mapping[int, float]) -> tuple[FormationFigures, FormationSeries]:
    ids = [u for u in sorted(tracks) if u in offsets and tracks[u].tracking.sum() >= 2]
    out = FormationFigures(uavs=ids, offsets={u: offsets[u].tolist() for u in ids})
    series = FormationSeries()
    # the plan's own shape error, measured the same way (what the flight can at best reproduce)
    planned = [u for u in sorted(trajs) if u in offsets]
    if len(planned) >= 2:
        tau = np.unique(np.concatenate([[w.t for w in trajs[u].waypoints] for u in planned]))
        tau = tau[(tau >= max(trajs[u].waypoints[0].t for u in planned))
                  & (tau <= min(trajs[u].waypoints[-1].t for u in planned))]
        if tau.size:
            pe = shape_errors(tau, {u: planned_positions(trajs[u], tau) for u in planned}, offsets)
            out.plan_rms_m, out.plan_max_m = float(np.sqrt(np.mean(pe**2))), float(np.max(pe))
            first = [anchors[u] for u in planned if u in anchors]
            if first:
                series = FormationSeries(plan_t=tau - trajs[planned[0]].waypoints[0].t + first[0], plan_error=pe)
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
    return out, FormationSeries(t=grid, error=err, plan_t=series.plan_t, plan_error=series.plan_error)


def _latest(stats: Sequence[Any]) -> Any | None:
    return max(stats, key=lambda s: (s.msg.stamp, s.rx)).msg if stats else None


def _gateway_figures(gw: Any) -> dict[str, Any]:
    """One gateway's :class:`~protocol.messages.LinkStats` as the report's plain figures."""
    return {"source": gw.source, "uptime_s": gw.uptime_s, "sessions": dict(gw.sessions), "rejected": dict(gw.rejected),
            "classes": {k: {"samples": v.samples, "bytes": v.bytes} for k, v in gw.classes.items()},
            "metrics": dict(gw.metrics)}


def _imagery_metrics(record: MissionRecord) -> dict[str, dict[str, float]]:
    """Latest ``uavN.camC.<name>`` metrics of the detector, grouped by camera (the latest of each instance,
    ``detector-K`` sharing the cameras by partition: services.detector.partition)."""
    out: dict[str, dict[str, float]] = {}
    sources = sorted({s.msg.source for s in record.detector_stats})
    latest = [x for src in sources if (x := _latest([s for s in record.detector_stats if s.msg.source == src])) is not None]
    for key, value in ((k, v) for st in latest for k, v in st.metrics.items()):
        parts = key.split(".")
        if len(parts) == 3 and parts[0].startswith("uav") and parts[1].startswith("cam"):
            out.setdefault(f"{parts[0]}.{parts[1]}", {})[parts[2]] = float(value)
    return dict(sorted(out.items()))


def _link_samples(record: MissionRecord, tracks: Mapping[int, Track]) -> LinkSamples:
    """Every flow's latency samples, seconds (the one place they are computed)."""
    return LinkSamples(
        telemetry=np.concatenate([tk.rx - tk.stamp for tk in tracks.values()]) if tracks else np.zeros(0),
        imagery=np.array([d.msg.stamp_report - d.msg.stamp_capture for d in record.defects
                          if d.msg.ok and d.msg.stamp_capture > 0], dtype=float),
        defect_reports=np.array([d.rx - d.msg.stamp_report for d in record.defects], dtype=float),
        command=np.array([a for c in record.commands for a in c.ack_s], dtype=float),
    )


def _links(record: MissionRecord, samples: LinkSamples, uav_figs: Mapping[int, UavFigures],
           imagery: Mapping[str, Mapping[str, float]]) -> dict[str, LinkFigures]:
    links: dict[str, LinkFigures] = {}
    # telemetry
    best, reliable = (record.transport.get(k, "") for k in ("best-effort", "reliable"))
    stream = best not in ("", "udp")  # the best-effort class on a TLS or TCP stream: a loss is a retransmission
    carried = f"best-effort class on {best.upper()} (a loss is a retransmission delay)" if stream else None
    tel = LinkFigures("telemetry", carried or "UDP: best-effort, drop", latency_kind="state age rx - stamp")
    for u, f in sorted(uav_figs.items()):
        if f.states:
            tel.per_uav[u] = {"received": f.telemetry_received, "sent": f.telemetry_sent,
                              "ratio": _ratio(f.telemetry_received, f.telemetry_sent)}
            tel.delivered += f.telemetry_received
            tel.sent += f.telemetry_sent
    tel.ratio = _ratio(tel.delivered, tel.sent)
    tel.latency_ms = latency_figures(samples.telemetry)
    links["telemetry"] = tel
    # imagery
    img = LinkFigures("imagery", f"RTP: sequenced frames, {carried}" if carried else "RTP: sequenced frames, best-effort",
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
    img.latency_ms = latency_figures(samples.imagery)
    links["imagery"] = img
    # defect reports back to the ground station
    rep = LinkFigures("defect_reports", "command class: reliable", latency_kind="delivery rx - stamp_report",
                      delivered=len(record.defects))
    rep.latency_ms = latency_figures(samples.defect_reports)
    links["defect_reports"] = rep
    # commands
    cmd = LinkFigures("command", f"{reliable.upper() if reliable else 'TCP'}: reliable, block", latency_kind="acknowledgement round trip ack_s",
                      delivered=sum(c.ok for c in record.commands), sent=len(record.commands))
    cmd.ratio = _ratio(cmd.delivered, cmd.sent)
    cmd.latency_ms = latency_figures(samples.command)
    for c in record.commands:
        row = cmd.per_uav.setdefault(c.uav, {"sent": 0, "ok": 0, "attempts": 0})
        row["sent"] = int(row["sent"] or 0) + 1
        row["ok"] = int(row["ok"] or 0) + int(c.ok)
        row["attempts"] = int(row["attempts"] or 0) + c.attempts
    cmd.per_uav = dict(sorted(cmd.per_uav.items()))
    links["command"] = cmd
    return links


def _captures(record: MissionRecord, trajs: Mapping[int, Trajectory]) -> tuple[CaptureFigures, set[tuple[int, int]]]:
    planned = planned_captures(trajs.values())
    ok = imaged_captures(d.msg for d in record.defects) if record.held_captures is None else \
        set(record.held_captures)  # checked against the frames the ground station received
    imaged = planned & ok
    c = CaptureFigures(planned=len(planned), imaged=len(imaged), ratio=_ratio(len(imaged), len(planned)),
                       failed_reports=sum(not d.msg.ok for d in record.defects),
                       unplanned_reports=len(ok - planned), missing=sorted(planned - imaged),
                       checked=record.held_captures is not None)
    return c, imaged


def as_record(record: MissionRecord | dict[str, Any]) -> MissionRecord:
    """A record, validated when given as a document (``record.json`` read back); ValueError otherwise."""
    if isinstance(record, MissionRecord):
        return record
    if isinstance(record, dict):
        return MissionRecord.model_validate(record)  # pydantic's ValidationError is a ValueError naming the field
    raise ValueError(f"record must be a MissionRecord, got {type(record).__name__}")


def analyse(record: MissionRecord) -> ReportFigures:
    """Every figure and series of the report, in one pass over the record (docs/report.md)."""
    tracks = _tracks(record)
    trajs = {tr.uav: tr for tr in record.plan.trajectories} if record.plan is not None else {}
    anchors = {u: a for u in sorted(tracks) if u in trajs and (a := _anchor(tracks[u], trajs[u])) is not None}
    captures, imaged = _captures(record, trajs)
    uavs: dict[int, UavFigures] = {}
    paths: dict[int, PathSeries] = {}
    goals = {u: goal_check((s.msg for s in record.states if s.msg.uav == u), tr) for u, tr in trajs.items()}
    for u in sorted(set(tracks) | set(trajs)):
        uavs[u], path = _uav_figures(u, tracks.get(u), trajs.get(u), imaged, anchors.get(u), goals.get(u))
        if path is not None:
            paths[u] = path
    table = DEFAULT_OFFSETS if record.scenario is None else record.scenario.offsets
    offsets = {u: np.array(table[u - 1]) for u in sorted(set(tracks) | set(trajs)) if 1 <= u <= len(table)}
    formation, formation_series = _formation(tracks, trajs, offsets, anchors)

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
    latencies = _link_samples(record, tracks)
    links = _links(record, latencies, uavs, imagery)

    planner = None
    if record.plan is not None:
        p = record.plan
        planner = PlannerFigures(
            algorithm=p.algorithm, seed=p.seed, cost=p.cost, initial_cost=p.convergence[0] if p.convergence else None,
            iterations=max(len(p.convergence) - 1, 0), convergence_iteration=convergence_iteration(p.convergence),
            planning_time_s=p.planning_time_s, plan_request_s=record.plan_request_s, collision_free=p.collision_free,
            waypoints={tr.uav: len(tr.waypoints) for tr in p.trajectories},
            duration_s={tr.uav: tr.waypoints[-1].t - tr.waypoints[0].t for tr in p.trajectories})
    per_source: dict[str, list[Any]] = {}
    for x in record.gateway_stats:  # one gateway per site (--sites)
        per_source.setdefault(x.msg.source, []).append(x)
    latest = {src: last for src, xs in sorted(per_source.items()) if (last := _latest(xs)) is not None}
    gateways = {src: _gateway_figures(gw) for src, gw in latest.items()}
    gateway = gateways[max(latest, key=lambda src: latest[src].stamp)] if latest else {}
    events = [{"rx": e.rx, "source": e.msg.source, "stamp": e.msg.stamp, "kind": e.msg.kind,
               "level": e.msg.level.value, "text": e.msg.text, "data": dict(e.msg.data)}
              for e in sorted(record.events, key=lambda e: e.rx)[:MAX_REPORT_EVENTS]]  # a flood stays out

    ts = [tk.t for tk in tracks.values() if tk.n]
    sim = float(max(t[-1] for t in ts) - min(t[0] for t in ts)) if ts else None
    st = [tk.stamp for tk in tracks.values() if tk.n]
    wall_states = float(max(s.max() for s in st) - min(s.min() for s in st)) if st else 0.0
    summary = ReportSummary(
        fleet=record.fleet, success=record.success, failures=list(record.failures), started=record.started,
        ended=record.ended, wall_time_s=(record.ended - record.started) if record.ended > 0 else None,
        speed=record.speed, sim_time_s=sim,
        measured_speed=(sim / wall_states) if sim is not None and wall_states > 0 else None, planner=planner, uavs=uavs,
        formation=formation, captures=captures, defects=defects, links=links, imagery=imagery, gateway=gateway,
        events=events, phases=dict(record.phases), notes=notes, faults=fault_figures(record), gateways=gateways)
    return ReportFigures(summary=summary, tracks=tracks, trajectories=trajs, anchors=anchors, paths=paths,
                         formation=formation_series, latencies=latencies, offsets=offsets, corners=corners,
                         obstacles=_obstacles(record))


def summarise(record: MissionRecord | dict[str, Any]) -> ReportSummary:
    """Every figure of the mission report (docs/report.md), without writing anything; ValueError for
    something that is neither a MissionRecord nor a valid record document."""
    return analyse(as_record(record)).summary

