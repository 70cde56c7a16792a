"""services.recording.record: the bounded live record, the output-folder check, a full disk under the mission log."""

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
from services.recording.record import EventRx, LiveRecord, MissionRecord, RecordingError, StateRx, check_output_folder


def _record() -> MissionRecord:
    return MissionRecord(fleet="test", speed=4.0, started=time.time())


def _state(i: int) -> StateRx:
    return StateRx(rx=time.time(), msg=VehicleState(uav=1, seq=i, t=i * 0.05, stamp=time.time(), pos=(i, 0, 10),
                                                    vel=(0, 0, 0), att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.MISSION))


def _event(i: int) -> EventRx:
    return EventRx(rx=time.time(), msg=Event(source="uav1", stamp=time.time(), kind="trust-refused", text="x" * 4000))


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


def test_a_full_disk_keeps_the_log_up_to_the_failure_and_says_where_the_rest_is():
    """On a full 64 KB tmpfs the mission log holds what fitted, recording goes on in memory, the error says so,
    and the report is computed from the in-memory record."""
    from services.recording.recorder import MissionLogWriter

    with tiny_tmpfs("64k") as mnt:
        rec = _record()
        writer = MissionLogWriter(None, mnt / "mission.mcap")
        live = LiveRecord(rec, writer)
        for _ in range(300):  # ~1.2 MB of the ground station's own events that do not compress: far more than fits
            event = Event(source="gcs", stamp=time.time(), kind="trust-refused", text=os.urandom(2000).hex())
            live.add("events", EventRx(rx=time.time(), msg=event), own=True)
        writer.finish(rec)
        assert len(rec.events) == 300  # nothing lost in memory
        assert writer.failed and "No space left" in writer.failed and str(mnt / "mission.mcap") in writer.failed
        assert report_record(writer, rec) is rec and "in-memory record" in rec.report_input
        assert any("in-memory record" in e for e in rec.recording_errors)


def test_output_folder_check_refuses_a_full_or_read_only_folder(tmp_path):
    assert check_output_folder(tmp_path / "new") == tmp_path / "new"
    with pytest.raises(RecordingError, match="MB free"):
        check_output_folder(tmp_path, min_free=10**18)
    (tmp_path / "file").write_text("x")
    with pytest.raises(RecordingError, match="not writable"):
        check_output_folder(tmp_path / "file" / "sub")


def test_mission_on_a_full_disk_is_refused_before_anything_starts():
    """``skynet mission --out`` on a 64 KB disk: a one-line error within seconds, no service started."""
    with tiny_tmpfs("64k") as mnt:
        proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--quiet", "--out", str(mnt / "r")],
                              capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "MB free" in proc.stderr and "router up" not in proc.stdout


def test_a_record_with_failures_reads_back_as_failed():
    """A log whose footer says success beside a failure (as runs that found a failure at their end wrote it) is
    reported as failed."""
    from services.recording.record import MissionRecord

    rec = MissionRecord.model_validate({"fleet": "f", "speed": 1.0, "started": 0.0, "success": True,
                                        "failures": ["never injected, the mission ended first: 40s cut uplinks"]})
    assert rec.success is False
    assert MissionRecord(fleet="f", speed=1.0, started=0.0, success=True).success


def test_a_header_naming_a_hostile_method_or_transport_is_refused():
    """The log's header names the detector's method and the links' protocols, which the report prints: markup,
    a line break or an unknown class there is a validation error, not text in report.md."""
    import pydantic
    import pytest

    from services.recording.record import MissionRecord

    base = {"fleet": "f", "speed": 1.0, "started": 0.0}
    for bad in ({"method": "<img src=x onerror=alert(1)>"}, {"method": "it+\n## Outcome: success"},
                {"transport": {"reliable": "tls | forged"}}, {"transport": {"telemetry": "udp"}}):
        with pytest.raises(pydantic.ValidationError):
            MissionRecord.model_validate({**base, **bad})
    ok = MissionRecord.model_validate({**base, "method": "it+r", "transport": {"reliable": "tls", "best-effort": "udp"}})
    assert ok.method == "it+r" and ok.transport["best-effort"] == "udp"
