"""The mission report's plots (figures -> plots): the paper's results figures, drawn from :class:`ReportFigures`.

Design notes: docs/report.md (services/gcs/plots.py).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from services.gcs.figures import ReportFigures, ReportSummary
from services.gcs.scoring import surface_uv
from services.recording.record import MissionRecord

__all__ = ["PLOTS", "write_plots"]

#: Most points drawn per line (longer series are decimated for plotting only).
_PLOT_POINTS = 4000
#: The plot files, in the order of the paper's results section.
PLOTS = ("trajectories.png", "altitudes.png", "path_error.png", "formation_error.png", "convergence.png",
         "defects_map.png", "links.png")


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


def _plot_trajectories(record: MissionRecord, figs: ReportFigures, path: Path) -> None:
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3d projection)
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = _figure(8.0, 6.5)
    ax = fig.add_subplot(projection="3d")
    tracks, trajs = figs.tracks, figs.trajectories
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
    start = record.scenario.start if record.scenario else (record.plan.centroid_path[0] if record.plan else None)
    goal = record.scenario.goal if record.scenario else (record.plan.centroid_path[-1] if record.plan else None)
    for end, marker, size, colour, label in ((start, "^", 60, "green", "start"), (goal, "*", 90, "red", "goal")):
        if end is not None:
            ax.scatter(*np.asarray(end, float), marker=marker, s=size, color=colour, label=label)
            pts.append(np.asarray(end, float).reshape(1, 3))
    if figs.corners:
        S = np.asarray(figs.corners, float)
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
    for x, y, r, h in figs.obstacles:
        if x + r < lo[0] or x - r > hi[0] or y + r < lo[1] or y - r > hi[1]:
            continue
        X = x + r * np.cos(theta)[None, :].repeat(2, 0)
        Y = y + r * np.sin(theta)[None, :].repeat(2, 0)
        Z = np.array([[0.0], [min(h, hi[2])]]).repeat(theta.size, 1)
        ax.plot_surface(X, Y, Z, color="grey", alpha=0.3, linewidth=0)
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]), xlabel="x east, m", ylabel="y north, m",
           zlabel="z up, m", title="Trajectories of the UAVs tracking the planned paths")
    ax.set_box_aspect(tuple(np.maximum(hi - lo, 1.0)))
    ax.legend(fontsize=7, loc="upper left")
    _save(fig, path)


def _save_series(fig, ax, path: Path, drawn: bool, empty: str, **labels: str) -> None:
    """Finish a plot of per-UAV lines over simulation time (or say there are none) and save it."""
    if not drawn:
        _no_data(ax, empty)
    ax.set(xlabel="time since the first state, s (simulation)", **labels)
    ax.grid(alpha=0.3)
    if drawn:
        ax.legend(fontsize=7)
    _save(fig, path)


def _plot_altitudes(figs: ReportFigures, path: Path) -> None:
    fig = _figure()
    ax = fig.add_subplot()
    t0 = figs.t0
    for u, tk in sorted(figs.tracks.items()):
        s = _thin(tk.n)
        ax.plot(tk.t[s] - t0, tk.pos[s, 2], "-", color=_colour(u), label=f"UAV {u} flown")
        tr = figs.trajectories.get(u)
        if tr is not None and u in figs.anchors:
            tw = np.array([w.t for w in tr.waypoints]) - tr.waypoints[0].t + figs.anchors[u] - t0
            ax.plot(tw, [w.pos[2] for w in tr.waypoints], "--", color=_colour(u), lw=1.0, label=f"UAV {u} planned")
    _save_series(fig, ax, path, bool(figs.tracks), "no data", ylabel="altitude z, m", title="Altitudes of the UAVs")


def _plot_path_error(figs: ReportFigures, path: Path) -> None:
    fig = _figure()
    ax = fig.add_subplot()
    t0 = figs.t0
    for u, ser in sorted(figs.paths.items()):
        s = _thin(ser.t.size)
        ax.plot(ser.t[s] - t0, ser.geometric[s], "-", color=_colour(u), label=f"UAV {u} to planned path")
        if ser.timed is not None:
            ax.plot(ser.t[s] - t0, ser.timed[s], ":", color=_colour(u), label=f"UAV {u} time-aligned")
    _save_series(fig, ax, path, bool(figs.paths), "no tracking states", ylabel="error, m",
                 title="Errors between the planned and flown paths")


def _plot_formation(figs: ReportFigures, path: Path) -> None:
    fig = _figure(7.0, 3.5)
    ax = fig.add_subplot()
    f, summary = figs.formation, figs.summary
    if f.t is not None and f.error is not None:
        s = _thin(f.t.size)
        ax.plot(f.t[s] - figs.t0, f.error[s], "-", color="k", label="flown")
        if f.plan_t is not None and f.plan_error is not None:
            s = _thin(f.plan_t.size)
            ax.plot(f.plan_t[s] - figs.t0, f.plan_error[s], "--", color="C0", lw=0.9,
                    label=f"planned (RMS {summary.formation.plan_rms_m:.2f} m)")
        ax.axhline(summary.formation.rms_m, color="C3", ls=":", lw=0.8, label=f"flown RMS {summary.formation.rms_m:.2f} m")
        ax.legend(fontsize=8)
    else:
        _no_data(ax, "fewer than two UAVs tracking together")
    ax.set(xlabel="time since the first state, s (simulation)", ylabel="formation RMS shape error, m",
           title="Formation error during the mission")
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
    ax.set(xlabel="iteration", ylabel="best cost J_F (P5)", title="Planner convergence")
    ax.grid(alpha=0.3)
    _save(fig, path)


def _plot_defects(record: MissionRecord, figs: ReportFigures, path: Path) -> None:
    from matplotlib.patches import Rectangle

    fig = _figure(9.0, 3.8)
    ax = fig.add_subplot()
    score = figs.summary.defects
    corners = figs.corners
    if corners:
        L = surface_uv(np.asarray(corners, float), corners)
        ax.add_patch(Rectangle((0, 0), L[1, 0], L[3, 1], fill=False, ec="k", lw=1.0))
        ax.set(xlim=(min(0.0, L[:, 0].min()) - 1, L[:, 0].max() + 1), ylim=(min(0.0, L[:, 1].min()) - 1, L[:, 1].max() + 1))
    found = set(score.found_ids) if score else set()
    for g in record.ground_truth:
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
    ax.set(xlabel="u along the bottom edge, m", ylabel="v up the surface, m")
    title = "Defects on the surface"
    if score:
        title += f": recall {score.recall:.2f}, precision {score.precision:.2f} (tolerance {score.tolerance_m:g} m)"
    ax.set_title(title, fontsize=10)
    _save(fig, path)


def _plot_links(figs: ReportFigures, path: Path) -> None:
    fig = _figure(7.0, 4.0)
    ax = fig.add_subplot()
    lat = figs.latencies
    data = {"telemetry\nstate age": lat.telemetry, "imagery\ncapture to report": lat.imagery,
            "defect report\ndelivery": lat.defect_reports, "command\nack": lat.command}
    data = {k: 1000.0 * v[np.isfinite(v)] for k, v in data.items() if np.size(v)}
    if data:
        ax.boxplot(list(data.values()), whis=(1, 99), showfliers=False)
        ax.set_xticks(range(1, len(data) + 1), list(data.keys()), fontsize=8)
        if min(float(np.min(v)) for v in data.values()) > 0:
            ax.set_yscale("log")
    else:
        _no_data(ax)
    ax.set(ylabel="latency, ms (whiskers p1-p99)", title="Latency per link class")
    ax.grid(alpha=0.3, axis="y")
    _save(fig, path)


def write_plots(record: MissionRecord, figs: ReportFigures, folder: Path) -> list[str]:
    """Draw every plot of :data:`PLOTS` into ``folder`` (an existing directory); the names written."""
    _plot_trajectories(record, figs, folder / "trajectories.png")
    _plot_altitudes(figs, folder / "altitudes.png")
    _plot_path_error(figs, folder / "path_error.png")
    _plot_formation(figs, folder / "formation_error.png")
    _plot_convergence(record, figs.summary, folder / "convergence.png")
    _plot_defects(record, figs, folder / "defects_map.png")
    _plot_links(figs, folder / "links.png")
    return list(PLOTS)

