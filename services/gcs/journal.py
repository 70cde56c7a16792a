"""The mission report computed from the mission's log (``mission.mcap``), live or afterwards.

Design notes: docs/report.md (services/gcs/journal.py).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from services.recording.record import MissionRecord

log = logging.getLogger("skynet.gcs.journal")

#: the mission's log in a report folder
LOG_NAME = "mission.mcap"


def _read_back(path: Path, found) -> str:
    """What the report's input was: the log, with its messages and the damaged ones skipped."""
    damaged = f", {found.damaged} damaged and skipped" if found.damaged else ""
    return f"{path} read back ({found.messages} messages{damaged})"


def report_record(writer, live: MissionRecord, logger: logging.Logger | None = None) -> MissionRecord:
    """The record the report is computed from: ``writer``'s log read back (a finished
    :class:`~services.recording.recorder.MissionLogWriter`), or ``live`` (the in-memory record) when there is no
    log, writing it failed, or it cannot be read back with its footer.

    Either way ``report_input`` says which, and why for the fallback."""
    logger = logger or log
    if writer is None:
        live.report_input = "the in-memory record (no mission log was asked for)"
        return live
    from services.recording.load import load_record

    path = writer.path
    why = writer.failed
    if why is None:
        try:
            back, found = load_record(path)
        except (OSError, ValueError) as exc:
            why = f"reading {path} back failed ({exc})"
        else:
            if found.footer:
                back.report_input = _read_back(path, found)
                return back
            why = f"{path} has no footer"
    note = (f"the report is computed from the in-memory record (bounded: {dict(live.not_kept) or 'nothing'} "
            f"not kept), not from the mission log: {why}")
    logger.error("%s", note)
    live.report_input = note
    if note not in live.recording_errors:
        live.recording_errors.append(note)
    return live


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skynet report", description="the mission report from its log alone")
    p.add_argument("record", help=f"a mission's report folder (skynet mission --out) or its log ({LOG_NAME})")
    p.add_argument("--out", default=None, help="report folder (default: the log's folder)")
    p.add_argument("--frames", default=None, metavar="DIR",
                   help="posed photos for the inspection section (default: the capture frames of the log)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    path = Path(args.record)
    if path.suffix == ".jsonl":  # a former journal: its folder's log is the record
        print(f"skynet report: {path.name} is no longer read; reporting from {LOG_NAME} beside it")
        path = path.parent
    if path.is_dir():
        path = path / LOG_NAME
    if not path.is_file():
        raise OSError(f"no mission log {path}")
    from services.recording.load import load_record

    from .report import write_report

    out = Path(args.out) if args.out else path.parent
    record, found = load_record(path)  # ValueError / OSError: a one-line error (services.cli)
    record.report_input = _read_back(path, found)
    summary = write_report(record, out, Path(args.frames) if args.frames else path)
    for note in found.notes(path):
        print(f"skynet report: {note}")
    cap = summary.captures
    print(f"report written to {out / 'report.md'}: success {summary.success}, {cap.imaged}/{cap.planned} "
          f"capture points imaged, {found.messages} messages ({found.damaged} damaged)")
    return 0 if found.footer else 1


if __name__ == "__main__":
    raise SystemExit(main())
