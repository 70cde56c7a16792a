"""services.gcs.journal: the mission report computed from the journal (record.jsonl) alone."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from services.gcs.journal import report_record
from services.recording.record import ITEM_MODELS, MissionRecord, Recorder, read_journal
from services.gcs.report import summarise, write_report
from tests.services.gcs.test_report import build_record

HEADER = {"fleet", "scenario", "speed", "started"}


def _journalled(tmp_path: Path, path: str | Path | None = None) -> tuple[MissionRecord, MissionRecord, Recorder]:
    """The synthetic mission of test_report recorded the ground station's way: the header's fields first,
    every list item through a Recorder (as the callbacks do), the rest set before closing (as run() does).
    Returns (the full record, the live record the Recorder kept, the Recorder, closed)."""
    full = build_record()
    live = MissionRecord(**{k: getattr(full, k) for k in HEADER})
    rec = Recorder(live, tmp_path / "record.jsonl" if path is None else path)
    for kind in ITEM_MODELS:
        for item in getattr(full, kind):
            rec.add(kind, item)
    for k, v in full:
        if k not in HEADER and k not in ITEM_MODELS:
            setattr(live, k, v)
    rec.close()
    return full, live, rec


def _figures(record: MissionRecord) -> dict:
    d = summarise(record).to_dict()
    d.pop("files", None)
    return d


def test_the_report_from_the_journal_equals_the_live_one(tmp_path):
    full, live, rec = _journalled(tmp_path)
    back = report_record(rec, live)
    assert back is not live and "read back" in back.report_input and not back.recording_errors
    for kind in ITEM_MODELS:
        assert getattr(back, kind) == getattr(full, kind), kind
    want, got = _figures(live), _figures(back)
    assert got == want
    # the figures the issue names: captures, formation RMS, per-UAV counts
    assert got["captures"]["imaged"] == want["captures"]["imaged"] > 0
    assert got["formation"]["rms_m"] == want["formation"]["rms_m"]
    assert {u: f["states"] for u, f in got["uavs"].items()} == {u: f["states"] for u, f in want["uavs"].items()}
    assert got["defects"] == want["defects"] and got["defects"]["n_truth"] == len(full.ground_truth)


def test_skynet_report_rebuilds_the_same_report_from_the_file_alone(tmp_path):
    _, live, rec = _journalled(tmp_path)
    write_report(report_record(rec, live), tmp_path / "live")
    proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(tmp_path / "record.jsonl"),
                           "--out", str(tmp_path / "again")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "report written to" in proc.stdout and "(0 damaged)" in proc.stdout
    a = json.loads((tmp_path / "live" / "report.json").read_text())
    b = json.loads((tmp_path / "again" / "report.json").read_text())
    assert a == b
    assert "computed from" in (tmp_path / "again" / "report.md").read_text()


def test_damaged_lines_are_counted_and_skipped(tmp_path):
    """Garbage bytes, an item that does not validate and a line cut short in the middle of the journal:
    three damaged lines, counted (with the first one's number), the rest read; the figures do not move."""
    _, live, rec = _journalled(tmp_path)
    lines = (tmp_path / "record.jsonl").read_bytes().splitlines(keepends=True)
    bad = [b"\x00\xff\xfe not json at all\n", b'{"k":"states","v":{"rx":"soon"}}\n', b'{"k":"states","v":{"rx":1.0,']
    damaged = lines[:5] + [bad[0]] + lines[5:40] + [bad[1]] + lines[40:-1] + [bad[2] + b"\n"] + lines[-1:]
    (tmp_path / "damaged.jsonl").write_bytes(b"".join(damaged))
    back, found = read_journal(tmp_path / "damaged.jsonl")
    assert found.damaged == 3 and found.first_damaged == 6 and found.footer
    assert found.lines == len(lines) + 3 and found.items == len(lines) - 2
    assert any("3 damaged line(s) skipped (the first is line 6)" in e for e in back.recording_errors)
    assert _figures(back) | {"failures": None} == _figures(live) | {"failures": None}


def test_a_journal_cut_before_its_footer_still_reads(tmp_path):
    _, live, rec = _journalled(tmp_path)
    data = (tmp_path / "record.jsonl").read_bytes()
    (tmp_path / "cut.jsonl").write_bytes(data[: data.rindex(b'"footer"') + 40])
    back, found = read_journal(tmp_path / "cut.jsonl")
    assert not found.footer and found.damaged == 1
    assert len(back.states) == len(live.states) and back.plan is None
    assert any("no footer" in e for e in back.recording_errors)
    proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(tmp_path / "cut.jsonl"),
                           "--out", str(tmp_path / "cut")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "no footer" in proc.stdout, proc.stdout + proc.stderr
    assert (tmp_path / "cut" / "report.md").exists()


def test_a_journal_that_could_not_be_written_falls_back_to_the_bounded_memory_record(tmp_path):
    """/dev/full: every write fails with ENOSPC (a full disk without root). The mission's record is the
    in-memory one, and the report says so and where the data went."""
    full, live, rec = _journalled(tmp_path, "/dev/full")
    assert rec.failed and "No space left" in rec.failed
    back = report_record(rec, live)
    assert back is live and "in-memory record" in back.report_input
    assert len(back.states) == len(full.states) and _figures(back)["captures"] == _figures(full)["captures"]
    write_report(back, tmp_path / "rep")
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "in-memory record" in md and "/dev/full" in md and "No space left" in md


def test_the_read_back_is_bounded_like_the_live_record(tmp_path):
    full, live, rec = _journalled(tmp_path)
    caps = {"states": 64, "events": 0}
    back, found = read_journal(tmp_path / "record.jsonl", caps)
    assert found.items == sum(len(getattr(full, k)) for k in ITEM_MODELS)
    assert len(back.states) <= 64 and len(back.states) + back.not_kept["states"] == len(full.states)
    assert back.states[0] == full.states[0] and back.states[-1] == full.states[-1]
    assert back.events == [] and back.not_kept["events"] == len(full.events)
