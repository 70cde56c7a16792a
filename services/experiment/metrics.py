"""What an experiment measures per run, read from the mission's ``report.json``, and per cell (pure).

Design notes: docs/experiments.md (services/experiment/metrics.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

__all__ = ["METRICS", "aggregate", "run_metrics"]

#: metric name -> (unit, description); the order of tables and results.json
METRICS: dict[str, tuple[str, str]] = {
    "success": ("", "mission succeeded"),
    "coverage": ("", "capture points imaged / planned"),
    "captures_imaged": ("", "capture points imaged"),
    "captures_planned": ("", "capture points planned"),
    "cmd_ack_ratio": ("", "commands acknowledged / sent"),
    "cmd_ack_p50_ms": ("ms", "command acknowledgement p50"),
    "cmd_ack_p95_ms": ("ms", "command acknowledgement p95"),
    "cmd_failed": ("", "commands not acknowledged"),
    "telemetry_ratio": ("", "states received / sent"),
    "telemetry_age_p50_ms": ("ms", "telemetry age p50"),
    "telemetry_age_p95_ms": ("ms", "telemetry age p95"),
    "img_delivered": ("", "capture frames delivered"),
    "img_missing": ("", "capture frames that never arrived (planned - delivered - late)"),
    "img_lost": ("", "capture frames lost (sequence gaps)"),
    "img_late": ("", "capture frames late"),
    "img_recovered": ("", "capture frames recovered"),
    "img_jitter_ms": ("ms", "RFC 3550 jitter (largest camera)"),
    "capture_to_report_p95_ms": ("ms", "capture to report p95"),
    "formation_rms_m": ("m", "formation error RMS"),
    "formation_max_m": ("m", "formation error max"),
    "defects_found": ("", "defects found"),
    "defects_planted": ("", "defects planted"),
    "defect_recall": ("", "defect recall"),
    "defect_precision": ("", "defect precision"),
    "wall_s": ("s", "run wall time"),
}


def _get(d: Any, *path: str) -> Any:
    for p in path:
        if not isinstance(d, Mapping) or p not in d:
            return None
        d = d[p]
    return d


def _num(x: Any) -> float | None:
    if isinstance(x, bool):
        return float(x)
    if isinstance(x, (int, float)) and math.isfinite(x):
        return float(x)
    return None


def _camera_sum(imagery: Mapping[str, Any], name: str) -> float | None:
    values = [_num(_get(m, name)) for m in imagery.values()]
    values = [v for v in values if v is not None]
    return float(sum(values)) if values else None


def run_metrics(report: Mapping[str, Any] | None, wall_s: float | None = None, hung: bool = False
                ) -> dict[str, float | None]:
    """The :data:`METRICS` of one run from its ``report.json`` (None or {} when there is none).

    Parts of the report that are missing or not of the expected shape give None, never an error.

    A figure the report does not have is None (e.g. no imagery statistics reached the ground
    station); a run without a report has ``success`` 0 and nothing else; a hung run (stopped at
    the timeout) has ``success`` 0 and whatever the report it left says.
    """
    out: dict[str, float | None] = dict.fromkeys(METRICS)
    out["wall_s"] = _num(wall_s)
    if not isinstance(report, Mapping) or not report:
        out["success"] = 0.0
        return out
    r = report
    out["success"] = 1.0 if r.get("success") is True and not hung else 0.0
    out["coverage"] = _num(_get(r, "captures", "ratio"))
    out["captures_imaged"] = _num(_get(r, "captures", "imaged"))
    out["captures_planned"] = _num(_get(r, "captures", "planned"))
    cmd = _get(r, "links", "command")
    out["cmd_ack_ratio"] = _num(_get(cmd, "ratio"))
    out["cmd_ack_p50_ms"] = _num(_get(cmd, "latency_ms", "p50"))
    out["cmd_ack_p95_ms"] = _num(_get(cmd, "latency_ms", "p95"))
    sent, ok = _num(_get(cmd, "sent")), _num(_get(cmd, "delivered"))
    out["cmd_failed"] = sent - ok if sent is not None and ok is not None else None
    tel = _get(r, "links", "telemetry")
    out["telemetry_ratio"] = _num(_get(tel, "ratio"))
    out["telemetry_age_p50_ms"] = _num(_get(tel, "latency_ms", "p50"))
    out["telemetry_age_p95_ms"] = _num(_get(tel, "latency_ms", "p95"))
    imagery = r.get("imagery")
    if isinstance(imagery, Mapping) and imagery:
        out["img_delivered"] = _camera_sum(imagery, "delivered")
        out["img_lost"] = _camera_sum(imagery, "lost")
        out["img_late"] = _camera_sum(imagery, "late")
        out["img_recovered"] = _camera_sum(imagery, "recovered")
        jit = [j for m in imagery.values() if (j := _num(_get(m, "jitter_ms"))) is not None]
        out["img_jitter_ms"] = max(jit) if jit else None
    planned = out["captures_planned"]
    if planned is not None:
        arrived = (out["img_delivered"] or 0.0) + (out["img_late"] or 0.0)
        out["img_missing"] = max(planned - arrived, 0.0)
    out["capture_to_report_p95_ms"] = _num(_get(r, "links", "imagery", "latency_ms", "p95"))
    out["formation_rms_m"] = _num(_get(r, "formation", "rms_m"))
    out["formation_max_m"] = _num(_get(r, "formation", "max_m"))
    out["defects_found"] = _num(_get(r, "defects", "n_found"))
    out["defects_planted"] = _num(_get(r, "defects", "n_truth"))
    out["defect_recall"] = _num(_get(r, "defects", "recall"))
    out["defect_precision"] = _num(_get(r, "defects", "precision"))
    return out


def _stats(values: Sequence[float]) -> dict[str, float] | None:
    if not values:
        return None
    return {"mean": sum(values) / len(values), "min": min(values), "max": max(values), "n": len(values)}


def aggregate(runs: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """One cell's figures from its runs (each ``{"status": ..., "metrics": {...}}``).

    Returns ``{"runs", "succeeded", "hung", "failed_to_report", "metrics": {name: {mean, min, max, n}
    or None}}``; a metric's statistics cover the runs that have it.

    >>> a = aggregate([{"status": "ok", "metrics": {"success": 1.0, "coverage": 1.0}},
    ...                {"status": "hung", "metrics": {"success": 0.0, "coverage": None}}])
    >>> a["runs"], a["succeeded"], a["hung"], a["metrics"]["success"]["mean"], a["metrics"]["coverage"]["n"]
    (2, 1, 1, 0.5, 1)
    """
    runs = list(runs)
    metrics: dict[str, Any] = {}
    for name in METRICS:
        vals = [v for r in runs if (v := _num((r.get("metrics") or {}).get(name))) is not None]
        metrics[name] = _stats(vals)
    return {
        "runs": len(runs),
        "succeeded": sum(1 for r in runs if _num((r.get("metrics") or {}).get("success")) == 1.0),
        "hung": sum(1 for r in runs if r.get("status") == "hung"),
        "failed_to_report": sum(1 for r in runs if r.get("status") == "no-report"),
        "metrics": metrics,
    }
