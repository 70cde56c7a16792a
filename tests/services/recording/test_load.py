"""The one mission record (services.recording): the ground station's entries and the bus's samples written to
one MCAP log by one writer, read back by one loader; the report computed from the log equals the live one,
and ``skynet report`` makes it from the file alone."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from protocol import codec, keys
from services.gcs.figures import summarise
from services.gcs.journal import report_record
from services.gcs.report import write_report
from services.recording.load import load_record
from services.recording.record import ITEM_MODELS, LiveRecord, MissionRecord
from services.recording.recorder import FOOTER_TOPIC, MissionLogWriter
from tests.services.gcs.test_report import build_record

HEADER = {"fleet", "scenario", "speed", "started"}


def bus_key(fleet: str, kind: str, msg) -> str | None:
    """The key a received item came on (None: an entry of the ground station's own)."""
    if kind == "states":
        return keys.state(fleet, msg.uav)
    if kind == "defects":
        return keys.defects(fleet)
    if kind == "detector_stats":
        return keys.rcu_stats(fleet, msg.source)
    return None


def logged(tmp_path: Path, path: str | Path | None = None, full: MissionRecord | None = None,
           caps: dict[str, int] | None = None) -> tuple[MissionRecord, MissionRecord, MissionLogWriter]:
    """The synthetic mission of test_report logged the ground station's way: states, defect reports and
    statistics as bus samples, commands and events as the ground station's own entries (through a LiveRecord,
    as the runner's callbacks do), the rest in the footer. Returns (full record, live record, finished writer)."""
    full = build_record() if full is None else full
    for kind in ("states", "defects", "events", "detector_stats"):  # as received: in receive order
        getattr(full, kind).sort(key=lambda item: item.rx)
    live = MissionRecord(**{k: getattr(full, k) for k in HEADER})
    writer = MissionLogWriter(None, tmp_path / "mission.mcap" if path is None else path)
    rec = LiveRecord(live, writer, caps)
    for kind in ITEM_MODELS:
        for item in getattr(full, kind):
            key = bus_key(full.fleet, kind, getattr(item, "msg", None))
            rec.add(kind, item, own=key is None)
            if key is not None:
                writer.sample(key, codec.encode(item.msg), item.rx)
    for k, v in full:
        if k not in HEADER and k not in ITEM_MODELS and k != "not_kept":
            setattr(live, k, v)
    writer.finish(live)
    return full, live, writer


def as_logged(items: list) -> list:
    """Items with their receive times as the log keeps them (integer nanoseconds)."""
    return [item.model_copy(update={"rx": round(item.rx * 1e9) / 1e9}) if hasattr(item, "rx") else item
            for item in items]


def _figures(record: MissionRecord) -> dict:
    d = summarise(record).to_dict()
    d.pop("files", None)
    return d


def test_the_report_from_the_log_equals_the_live_one(tmp_path):
    full, live, writer = logged(tmp_path)
    back = report_record(writer, live)
    assert back is not live and "read back" in back.report_input and not back.recording_errors
    for kind in ITEM_MODELS:
        assert as_logged(getattr(back, kind)) == as_logged(getattr(full, kind)), kind
    want = _figures(live.model_copy(update={k: as_logged(getattr(live, k)) for k in ITEM_MODELS}))
    got = _figures(back)
    assert got == want
    assert got["captures"]["imaged"] == want["captures"]["imaged"] > 0
    assert got["defects"] == want["defects"] and got["defects"]["n_truth"] == len(full.ground_truth)


def test_skynet_report_rebuilds_the_same_report_from_the_file_or_its_folder(tmp_path):
    _, live, writer = logged(tmp_path)
    write_report(report_record(writer, live), tmp_path / "live")
    a = json.loads((tmp_path / "live" / "report.json").read_text())
    for target in (tmp_path / "mission.mcap", tmp_path):
        out = tmp_path / f"again-{target.name}"
        proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(target), "--out", str(out)],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert "report written to" in proc.stdout and "(0 damaged)" in proc.stdout
        assert json.loads((out / "report.json").read_text()) == a
        assert "computed from" in (out / "report.md").read_text()


def test_memory_is_bounded_and_the_log_has_everything(tmp_path):
    """A 10,000-event flood (4 KB each) keeps at most the cap in memory; states are decimated, not cut; the
    log has everything, and read back with the same caps it gives the same bounded record."""
    from tests.services.recording.test_record import _event, _record, _state

    caps = {"events": 100, "states": 64}
    full = _record()
    full.events = [_event(i) for i in range(10_000)]
    full.states = [_state(i) for i in range(1000)]
    _, live, _ = logged(tmp_path, full=full, caps=caps)
    assert len(live.events) == 100 and live.not_kept["events"] == 9_900
    assert len(live.states) <= 64 and live.states[-1].msg.seq == 999
    back, found = load_record(tmp_path / "mission.mcap", caps={})  # no caps: everything the log has
    assert len(back.events) == 10_000 and len(back.states) == 1000 and found.footer
    again, _ = load_record(tmp_path / "mission.mcap", caps=caps)
    assert as_logged(again.events) == as_logged(live.events) and as_logged(again.states) == as_logged(live.states)
    assert again.not_kept == live.not_kept


def test_a_damaged_entry_is_counted_and_skipped_and_a_log_without_footer_still_reads(tmp_path):
    full = build_record()
    full.states.sort(key=lambda item: item.rx)
    path = tmp_path / "mission.mcap"
    writer = MissionLogWriter(None, path)
    LiveRecord(MissionRecord(**{k: getattr(full, k) for k in HEADER}), writer)
    for item in full.states:
        writer.sample(keys.state(full.fleet, item.msg.uav), codec.encode(item.msg), item.rx)
    writer.sample(keys.state(full.fleet, 2), codec.encode(full.states[0].msg), full.states[0].rx)  # uav 1's body
    writer.sample(keys.state(full.fleet, 1), b"\x93 not a message", full.started + 1)  # logged raw: not a state
    writer._ring.push(("json", "/skynet/record/commands", "skynet.record.CommandRecord", {}, '{"uav": "x"}', 1.0))
    writer._ring.push(("json", FOOTER_TOPIC, "skynet.record.Footer", {}, "[1, 2", 2.0))
    writer.close()  # interrupted: no footer that reads
    back, found = load_record(path)
    assert found.damaged == 2 and not found.footer
    assert as_logged(back.states) == as_logged(full.states)  # the forged one (a UAV speaking for another) is not taken
    assert back.plan is None and any("no footer" in e for e in back.recording_errors)
    proc = subprocess.run([sys.executable, "-m", "services.cli", "report", str(path), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and "no footer" in proc.stdout, proc.stdout + proc.stderr
    assert (tmp_path / "o" / "report.md").exists()


def test_a_log_that_could_not_be_written_falls_back_to_the_bounded_memory_record(tmp_path):
    """/dev/full: every write fails with ENOSPC (a full disk without root). The mission's record is the
    in-memory one, and the report says so and where the data went."""
    full, live, writer = logged(tmp_path, "/dev/full")
    assert writer.failed and "No space left" in writer.failed
    back = report_record(writer, live)
    assert back is live and "in-memory record" in back.report_input
    assert len(back.states) == len(full.states) and _figures(back)["captures"] == _figures(full)["captures"]
