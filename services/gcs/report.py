"""The mission report: figures, plots and a Markdown page from a recorded mission.

Design notes: docs/report.md (services/gcs/report.py).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from services.gcs.figures import ReportSummary, analyse, as_record
from services.gcs.markdown import markdown
from services.gcs.plots import write_plots
from services.inspection.mission import append_deliverable
from services.recording.record import MissionRecord

__all__ = ["write_report"]


# ============================================================================ entry point
def write_report(record: MissionRecord | dict[str, Any], folder: str | Path,
                 frames: str | Path | None = None) -> ReportSummary:
    """Write the mission report of ``record`` into ``folder`` (created if needed): ``record.json``,
    ``report.json``, ``report.md`` and the plots :data:`PLOTS` (always the same set: an empty plot says so),
    returning the summary. ``frames``: the captures for the deliverable (default ``folder/frames``).
    ValueError as :func:`services.gcs.figures.summarise`, or when ``folder`` is not a directory."""
    record = as_record(record)
    figs = analyse(record)
    summary = figs.summary
    out = Path(folder)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    (out / "record.json").write_text(record.model_dump_json())
    plots = write_plots(record, figs, out)
    summary.files = ["record.json", "report.json", "report.md", *plots]
    (out / "report.md").write_text(markdown(record, summary))
    append_deliverable(record, out, summary.files, frames)  # mosaic, defect table
    (out / "report.json").write_text(json.dumps(summary.to_dict(), indent=1, allow_nan=False))
    return summary
