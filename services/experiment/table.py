"""The experiment's Markdown table: one row per cell, means over the repeats (pure).

Design notes: docs/experiments.md (services/experiment/table.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

__all__ = ["COLUMNS", "markdown"]

#: (header, metric, format, scale): the table's figure columns after the cell's own
COLUMNS: tuple[tuple[str, str, str, float], ...] = (
    ("coverage %", "coverage", "{:.0f}", 100.0),
    ("frames delivered", "img_delivered", "{:.0f}", 1.0),
    ("missing", "img_missing", "{:.0f}", 1.0),
    ("lost (gaps)", "img_lost", "{:.0f}", 1.0),
    ("late", "img_late", "{:.0f}", 1.0),
    ("recovered", "img_recovered", "{:.0f}", 1.0),
    ("RTP jitter ms", "img_jitter_ms", "{:.0f}", 1.0),
    ("capture->report p95 ms", "capture_to_report_p95_ms", "{:.0f}", 1.0),
    ("acks %", "cmd_ack_ratio", "{:.0f}", 100.0),
    ("ack p95 ms", "cmd_ack_p95_ms", "{:.0f}", 1.0),
    ("telemetry %", "telemetry_ratio", "{:.1f}", 100.0),
    ("telemetry age p95 ms", "telemetry_age_p95_ms", "{:.0f}", 1.0),
    ("formation RMS m", "formation_rms_m", "{:.2f}", 1.0),
)


def _fig(stats: Mapping[str, float] | None, fmt: str, scale: float) -> str:
    if not stats:
        return "-"
    mean = fmt.format(stats["mean"] * scale)
    lo, hi = fmt.format(stats["min"] * scale), fmt.format(stats["max"] * scale)
    return mean if lo == hi else f"{mean} ({lo}-{hi})"


def _defects(m: Mapping[str, Any]) -> str:
    found, planted = m.get("defects_found"), m.get("defects_planted")
    if not found or not planted:
        return "-"
    return f"{found['mean']:.1f}/{planted['mean']:.0f}"


def markdown(cells: Sequence[Mapping[str, Any]]) -> str:
    """The table of ``cells`` (each ``{"cell": {loss_pct, delay_ms, jitter_ms, recovery}, **aggregate}``).

    >>> row = {"cell": {"loss_pct": 5.0, "delay_ms": 0.0, "jitter_ms": 0.0, "recovery": True},
    ...        "runs": 1, "succeeded": 1, "hung": 0, "failed_to_report": 0,
    ...        "metrics": {"coverage": {"mean": 1.0, "min": 1.0, "max": 1.0, "n": 1}}}
    >>> print(markdown([row]).splitlines()[2][:40])
    | 5 | 0 | 0 | on | 1/1 | 100 | - | - | -
    """
    head = ["loss %", "delay ms", "jitter ms", "recovery", "success", *(c[0] for c in COLUMNS),
            "defects found/planted", "notes"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in cells:
        cell, m = c["cell"], c.get("metrics") or {}
        notes = []
        if c.get("hung"):
            notes.append(f"{c['hung']} hung")
        if c.get("failed_to_report"):
            notes.append(f"{c['failed_to_report']} without report")
        row = [f"{cell['loss_pct']:g}", f"{cell['delay_ms']:g}", f"{cell['jitter_ms']:g}",
               "on" if cell["recovery"] else "off", f"{c.get('succeeded', 0)}/{c.get('runs', 0)}",
               *(_fig(m.get(metric), fmt, scale) for _, metric, fmt, scale in COLUMNS),
               _defects(m), ", ".join(notes)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)
