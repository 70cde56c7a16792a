"""The experiment's figures (matplotlib, Agg canvas, PNG): each a metric against loss or delay.

Design notes: docs/experiments.md (services/experiment/plots.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["PLOTS", "write_plots"]


def _figure(n: int = 1):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0 * n, 4.2), dpi=100)
    FigureCanvasAgg(fig)
    return fig, [fig.add_subplot(1, n, i + 1) for i in range(n)]


def _series(cells: Sequence[Mapping[str, Any]], metric: str, x: str, group: Sequence[str], scale: float = 1.0
            ) -> dict[tuple, tuple[list[float], list[float], list[float], list[float]]]:
    """group key -> (x, mean, min, max), sorted by x; cells without the metric left out."""
    out: dict[tuple, list[tuple[float, float, float, float]]] = {}
    for c in cells:
        st = (c.get("metrics") or {}).get(metric)
        if not st:
            continue
        cell = c["cell"]
        key = tuple(cell[g] for g in group)
        out.setdefault(key, []).append((cell[x], st["mean"] * scale, st["min"] * scale, st["max"] * scale))
    return {k: tuple(map(list, zip(*sorted(v)))) for k, v in sorted(out.items())}  # type: ignore[misc]


def _label(key: tuple, group: Sequence[str]) -> str:
    parts = []
    for name, v in zip(group, key):
        if name == "recovery":
            parts.append("recovery " + ("on" if v else "off"))
        elif name == "loss_pct":
            parts.append(f"loss {v:g}%")
        else:
            parts.append(f"{name.split('_')[0]} {v:g} ms")
    return ", ".join(parts)


def _plot(ax, cells, metric: str, x: str, group: Sequence[str], ylabel: str, xlabel: str, scale: float = 1.0,
          varying: Sequence[str] = ()) -> None:
    series = _series(cells, metric, x, group, scale)
    if not series:
        ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes, color="grey")
    shown = [g for g in group if g in varying]

    def base(key: tuple) -> tuple:  # the line's colour: everything but recovery (which sets the dash)
        return tuple(v for v, g in zip(key, group) if g != "recovery")

    bases = sorted({base(k) for k in series})
    for key, (xs, mean, lo, hi) in series.items():
        rec = dict(zip(group, key)).get("recovery", True)
        colour = f"C{bases.index(base(key)) % 10}"
        err = [[m - a for m, a in zip(mean, lo)], [b - m for m, b in zip(mean, hi)]]
        ax.errorbar(xs, mean, yerr=err if any(e > 0 for e in err[0] + err[1]) else None, marker="o",
                    linestyle="-" if rec else "--", color=colour, capsize=3,
                    label=_label(tuple(k for k, g in zip(key, group) if g in shown), shown) or None)
    if scale == 100.0:  # a percentage
        ax.set_ylim(-3, 103)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    if series and shown:
        ax.legend(fontsize=7)


_BY_DELAY = ("delay_ms", "jitter_ms", "recovery")
_LOSS = "random loss on the impaired links (%)"
#: file -> panels (metric, x, lines by, y label, x label, scale, title)
FIGURES: tuple[tuple[str, tuple[tuple[str, str, tuple[str, ...], str, str, float, str], ...]], ...] = (
    ("coverage.png", (
        ("coverage", "loss_pct", _BY_DELAY, "capture coverage (%)", _LOSS, 100.0, "capture coverage"),
        ("success", "loss_pct", _BY_DELAY, "missions succeeded (%)", _LOSS, 100.0, "mission success"))),
    ("imagery.png", (
        ("img_recovered", "loss_pct", _BY_DELAY, "capture frames recovered", _LOSS, 1.0, "imagery: recovered"),
        ("img_missing", "loss_pct", _BY_DELAY, "capture frames never delivered", _LOSS, 1.0, "imagery: missing"))),
    ("telemetry.png", (
        ("telemetry_age_p95_ms", "loss_pct", _BY_DELAY, "telemetry age p95 (ms)", _LOSS, 1.0, "telemetry age"),
        ("telemetry_ratio", "loss_pct", _BY_DELAY, "telemetry delivered (%)", _LOSS, 100.0, "telemetry delivery"))),
    ("commands.png", (
        ("cmd_ack_p95_ms", "delay_ms", ("loss_pct", "jitter_ms", "recovery"), "command acknowledgement p95 (ms)",
         "one-way delay on the impaired links (ms)", 1.0, "command acknowledgement latency"),)),
)
PLOTS = tuple(name for name, _ in FIGURES)


def write_plots(cells: Sequence[Mapping[str, Any]], folder: str | Path) -> list[str]:
    """Write :data:`PLOTS` into ``folder``; returns the file names."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    varying = [k for k in ("loss_pct", "delay_ms", "jitter_ms", "recovery") if len({c["cell"][k] for c in cells}) > 1]
    for name, panels in FIGURES:
        fig, axes = _figure(len(panels))
        for ax, (metric, x, group, ylabel, xlabel, scale, title) in zip(axes, panels):
            _plot(ax, cells, metric, x, group, ylabel, xlabel, scale, varying)
            ax.set_title(title)
        fig.tight_layout()
        fig.savefig(folder / name)
    return list(PLOTS)
