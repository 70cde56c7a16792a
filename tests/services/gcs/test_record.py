"""services.gcs.record: the streamed, bounded mission record and the output-folder check."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from protocol.messages import Event, Mode, VehicleState
from services.gcs.journal import report_record
from services.gcs.record import (
    EventRx,
    MissionRecord,
    Recorder,
    RecordingError,
    StateRx,
    check_output_folder,
    load_journal,
)


def _record() -> MissionRecord:
    return MissionRecord(fleet="test", speed=4.0, started=time.time())


def _state(i: int) -> StateRx:
    return StateRx(rx=time.time(), msg=VehicleState(uav=1, seq=i, t=i * 0.05, stamp=time.time(), pos=(i, 0, 10),
                                                    vel=(0, 0, 0), att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION))


def _event(i: int) -> EventRx:
    return EventRx(rx=time.time(), msg=Event(source="uav1", stamp=time.time(), kind="flood", text="x" * 4000))


def test_journal_streams_every_item_and_the_record_is_rebuilt_from_it(tmp_path):
    rec = _record()
    r = Recorder(rec, tmp_path / "record.jsonl")
    for i in range(500):
        r.add("states", _state(i))
    r.add("events", _event(0))
    rec.success, rec.failures = False, ["because"]
    r.close()
    back = load_journal(tmp_path / "record.jsonl")
    assert [s.msg.seq for s in back.states] == list(range(500))
    assert len(back.events) == 1 and back.failures == ["because"] and back.fleet == "test"
    assert not rec.recording_errors


def test_memory_is_bounded_and_the_journal_has_everything(tmp_path):
    """A 10,000-event flood (4 KB each) keeps at most the cap in memory; states are decimated, not cut."""
    rec = _record()
    r = Recorder(rec, tmp_path / "record.jsonl", caps={"events": 100, "states": 64})
    for i in range(10_000):
        r.add("events", _event(i))
    for i in range(1000):
        r.add("states", _state(i))
    r.close()
    assert len(rec.events) == 100 and rec.not_kept["events"] == 9_900
    assert len(rec.states) <= 64 and rec.states[0].msg.seq == 0 and rec.states[-1].msg.seq == 999
    assert len(rec.states) + rec.not_kept["states"] == 1000
    back = load_journal(tmp_path / "record.jsonl", caps={})  # no caps: everything the journal has
    assert len(back.events) == 10_000 and len(back.states) == 1000
    again = load_journal(tmp_path / "record.jsonl", caps={"events": 100, "states": 64})  # read back bounded
    assert again.events == rec.events and again.states == rec.states and again.not_kept == rec.not_kept
    assert len(rec.model_dump_json()) < 1_000_000  # what record.json would hold


def test_a_cut_last_line_is_ignored(tmp_path):
    rec = _record()
    r = Recorder(rec, tmp_path / "j.jsonl")
    for i in range(10):
        r.add("states", _state(i))
    r.close()
    data = (tmp_path / "j.jsonl").read_bytes()
    cut = data[: data.rindex(b'"footer"') + 30]  # the footer cut in the middle (disk full, crash)
    (tmp_path / "cut.jsonl").write_bytes(cut)
    back = load_journal(tmp_path / "cut.jsonl")
    assert len(back.states) == 10
    with pytest.raises(ValueError, match="no header"):
        (tmp_path / "empty.jsonl").write_text("")
        load_journal(tmp_path / "empty.jsonl")


@contextlib.contextmanager
def tiny_tmpfs(size: str):
    """A tmpfs of ``size`` mounted on a fresh folder (needs root)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    mnt = Path(f"/tmp/skynet-tiny-{uuid.uuid4().hex[:8]}")
    mnt.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True,
                          text=True)
    if proc.returncode != 0:
        mnt.rmdir()
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=False)
        mnt.rmdir()


@pytest.mark.root
def test_a_full_disk_keeps_the_record_up_to_the_failure_and_says_where_the_rest_is():
    """on a full 64 KB tmpfs the mission record used to be lost whole (0-byte files at the end).
    Now the journal holds everything up to the failure, recording goes on in memory, and the error says so."""
    with tiny_tmpfs("64k") as mnt:
        rec = _record()
        r = Recorder(rec, mnt / "record.jsonl")
        for i in range(300):  # ~1.2 MB of events: far more than fits
            r.add("events", _event(i))
            if i % 50 == 0:
                time.sleep(0.6)  # let the writer flush (FLUSH_S) so that the disk fills while we record
        r.close()
        assert len(rec.events) == 300  # nothing lost in memory
        assert rec.recording_errors and "No space left" in rec.recording_errors[0]
        assert str(mnt / "record.jsonl") in rec.recording_errors[0] and "in memory" in rec.recording_errors[0]
        back = load_journal(mnt / "record.jsonl")
        assert 0 < len(back.events) < 300  # the record up to the failure is kept
        assert [e.msg.kind for e in back.events] == ["flood"] * len(back.events)
        # the report is then computed from the in-memory record, and says so (services.gcs.journal)
        assert report_record(r, rec) is rec and "in-memory record" in rec.report_input


def test_output_folder_check_refuses_a_full_or_read_only_folder(tmp_path):
    assert check_output_folder(tmp_path / "new") == tmp_path / "new"
    with pytest.raises(RecordingError, match="MB free"):
        check_output_folder(tmp_path, min_free=10**18)
    (tmp_path / "file").write_text("x")
    with pytest.raises(RecordingError, match="not writable"):
        check_output_folder(tmp_path / "file" / "sub")


@pytest.mark.root
def test_mission_on_a_full_disk_is_refused_before_anything_starts():
    """``skynet mission --out`` on a 64 KB disk: a one-line error within seconds, no service started."""
    with tiny_tmpfs("64k") as mnt:
        proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--quiet", "--out", str(mnt / "r")],
                              capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "MB free" in proc.stderr and "router up" not in proc.stdout
