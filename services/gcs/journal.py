"""The mission report computed from the ground station's journal (``record.jsonl``), live or afterwards.

At the end of a mission the ground station reads its journal back (:func:`services.gcs.record.read_journal`:
line by line, into a record bounded like the live one) and computes the report from that, so the report's
input is the file on disk and ``skynet report record.jsonl`` makes the same report from the file alone.
When the journal could not be written (a write error, a full disk: :class:`~services.gcs.record.Recorder`
kept the mission flying and said where the data went), or cannot be read back whole, the report is
computed from the in-memory record instead (bounded by :data:`~services.gcs.record.CAPS`), and says so
(``report_input``, ``recording_errors``).

    skynet report reports/mission-<time>/record.jsonl [--out FOLDER]
    skynet report reports/mission-<time>/mission.mcap [--out FOLDER]

The inspection section (mosaic, defect table) is rebuilt from the captures the detector kept, ``frames/``
beside the journal (``--frames DIR``), as the mission's own report was.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from .record import MissionRecord, Recorder, read_journal

log = logging.getLogger("skynet.gcs.journal")


def _read_back(path: Path, found) -> str:
    """What the report's input was: the journal, with its lines and the damaged ones skipped."""
    damaged = f", {found.damaged} damaged and skipped" if found.damaged else ""
    return f"{path} read back ({found.lines} lines{damaged})"


def report_record(recorder: Recorder, live: MissionRecord, logger: logging.Logger | None = None) -> MissionRecord:
    """The record the report is computed from: ``recorder``'s journal read back, or ``live`` (the in-memory
    record) when there is no journal, writing it failed, or it cannot be read back with its footer.

    Call after ``recorder.close()``. Either way ``report_input`` says which, and why for the fallback."""
    logger = logger or log
    path = recorder.path
    if path is None:
        live.report_input = "the in-memory record (no journal was asked for)"
        return live
    why = recorder.failed
    if why is None:
        try:
            back, found = read_journal(path)
        except (OSError, ValueError) as exc:
            why = f"reading {path} back failed ({exc})"
        else:
            if found.footer:
                back.report_input = _read_back(path, found)
                return back
            why = f"{path} has no footer"
    note = (f"the report is computed from the in-memory record (bounded: {dict(live.not_kept) or 'nothing'} "
            f"not kept), not from the journal: {why}")
    logger.error("%s", note)
    live.report_input = note
    if note not in live.recording_errors:
        live.recording_errors.append(note)
    return live


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="skynet report", description="the mission report from its journal alone")
    p.add_argument("journal", help="record.jsonl of a mission (skynet mission / skynet gcs mission --out), or its "
                                   "MCAP log (mission.mcap)")
    p.add_argument("--out", default=None, help="report folder (default: the journal's folder)")
    p.add_argument("--frames", default=None, metavar="DIR",
                   help="the captures the detector kept, for the inspection section (default: frames/ beside "
                        "the journal)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    path = Path(args.journal)
    from .report import write_report

    out = Path(args.out) if args.out else path.parent
    frames = Path(args.frames) if args.frames else path.parent / "frames"
    if path.suffix == ".mcap":  # the MCAP log's mission record (services.recording.rebuild)
        from mcap.exceptions import McapError

        from services.recording.rebuild import rebuild

        try:
            record = rebuild(path)  # NotAMissionLog (a ValueError): a one-line error (services.cli)
        except (McapError, EOFError) as exc:
            raise ValueError(f"{path}: not an MCAP mission log ({exc})") from None
        record.report_input = f"{path} rebuilt"
        summary = write_report(record, out, frames)
        cap = summary.captures
        print(f"report written to {out / 'report.md'}: success {summary.success}, {cap.imaged}/{cap.planned} "
              f"capture points imaged, rebuilt from {path}")
        return 0
    record, found = read_journal(path)  # ValueError / OSError: a one-line error (services.cli)
    record.report_input = _read_back(path, found)
    summary = write_report(record, out, frames)
    for note in found.notes(path):
        print(f"skynet report: {note}")
    cap = summary.captures
    print(f"report written to {out / 'report.md'}: success {summary.success}, {cap.imaged}/{cap.planned} "
          f"capture points imaged, {found.lines} journal lines ({found.damaged} damaged)")
    return 0 if found.footer else 1


if __name__ == "__main__":
    raise SystemExit(main())
