"""The experiment's figures (matplotlib, Agg canvas, PNG): each a metric against loss or delay.

- ``coverage.png``: capture coverage and mission success against loss, one line per delay
  (and jitter), solid with recovery on, dashed with it off: what recovery buys under loss;
- ``imagery.png``: capture frames recovered and never delivered against loss;
- ``telemetry.png``: telemetry age p95 and delivery ratio against loss, per delay;
- ``commands.png``: command acknowledgement p95 against delay, one line per loss.

Points are means over the repeats, with min-max error bars when there are several.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["PLOTS", "write_plots"]

PLOTS = ("coverage.png", "imagery.png", "telemetry.png", "commands.png")


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


def write_plots(cells: Sequence[Mapping[str, Any]], folder: str | Path) -> list[str]:
    """Write :data:`PLOTS` into ``folder``; returns the file names."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    varying = [k for k in ("loss_pct", "delay_ms", "jitter_ms", "recovery")
               if len({c["cell"][k] for c in cells}) > 1]
    by_delay = ("delay_ms", "jitter_ms", "recovery")
    loss = "random loss on the impaired links (%)"

    fig, (a, b) = _figure(2)
    _plot(a, cells, "coverage", "loss_pct", by_delay, "capture coverage (%)", loss, 100.0, varying)
    _plot(b, cells, "success", "loss_pct", by_delay, "missions succeeded (%)", loss, 100.0, varying)
    a.set_title("capture coverage")
    b.set_title("mission success")
    fig.tight_layout()
    fig.savefig(folder / "coverage.png")

    fig, (a, b) = _figure(2)
    _plot(a, cells, "img_recovered", "loss_pct", by_delay, "capture frames recovered", loss, 1.0, varying)
    _plot(b, cells, "img_missing", "loss_pct", by_delay, "capture frames never delivered", loss, 1.0, varying)
    a.set_title("imagery: recovered")
    b.set_title("imagery: missing")
    fig.tight_layout()
    fig.savefig(folder / "imagery.png")

    fig, (a, b) = _figure(2)
    _plot(a, cells, "telemetry_age_p95_ms", "loss_pct", by_delay, "telemetry age p95 (ms)", loss, 1.0, varying)
    _plot(b, cells, "telemetry_ratio", "loss_pct", by_delay, "telemetry delivered (%)", loss, 100.0, varying)
    a.set_title("telemetry age")
    b.set_title("telemetry delivery")
    fig.tight_layout()
    fig.savefig(folder / "telemetry.png")

    fig, (a,) = _figure(1)
    _plot(a, cells, "cmd_ack_p95_ms", "delay_ms", ("loss_pct", "jitter_ms", "recovery"),
          "command acknowledgement p95 (ms)", "one-way delay on the impaired links (ms)", 1.0, varying)
    a.set_title("command acknowledgement latency")
    fig.tight_layout()
    fig.savefig(folder / "commands.png")
    return list(PLOTS)
