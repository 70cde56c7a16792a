"""One deliverable from every path: a real mission (the launcher, secure by default), ``skynet report`` of its
log, and its replay (``skynet replay`` onto a live network, recorded there by a ground station's log writer) make
the same inspection section: the same defects, the same counts, the same scoring against the wall's truth."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.messages import CommandAck, MissionPlan
from protocol.signing import unverified_inner
from services.gcs.figures import summarise
from services.gcs.report import write_report
from services.recording.load import load_record
from services.recording.mcap_log import bus_bytes, captures, read
from services.recording.recorder import MissionLogWriter
from tests.conftest import wait_until


def _figures(figures: dict) -> dict:
    return {k: v for k, v in json.loads(json.dumps(figures)).items() if k != "files"}


def _inspection(folder: Path) -> tuple[str | None, list[dict]]:
    """The inspection section's count sentence and its defect table (inspection/defects.json)."""
    m = re.search(r"\*\*(\d+ defects \([^)]*\))\*\*.*?\(by (\d+ of \d+ captures)", (folder / "report.md").read_text())
    table = json.loads((folder / "inspection" / "defects.json").read_text())
    return (m.group(1) + ", " + m.group(2) if m else None), table["defects"]


@pytest.mark.mission
def test_the_mission_its_log_and_its_replay_make_one_deliverable(nominal_mission, group, gateway,
                                                                  tmp_path: Path) -> None:
    out = nominal_mission.out
    assert nominal_mission.proc.returncode == 0, nominal_mission.failure()
    live = json.loads((out / "report.json").read_text())
    path = out / "mission.mcap"
    record, found = load_record(path)
    assert found.footer and not found.damaged
    record.report_input = json.loads((out / "record.json").read_text())["report_input"]
    assert _figures(summarise(record).to_dict()) == _figures(live)  # the mission's report is the log's
    assert live["captures"]["imaged"] == live["captures"]["planned"] > 0

    # every command the ground station sent is in the log with its acknowledgement, and the plan with it
    items = list(read(path))
    queries = [i for i in items if i.kind == "query" and i.topic.endswith("/cmd")]
    replies = [i.message() for i in items if i.kind == "reply" and i.topic.endswith("/cmd")]
    assert len(queries) == len(replies) == sum(c.attempts for c in record.commands) > 0
    sent = [unverified_inner(q.message()) for q in queries]  # signed commands: the log keeps the envelope
    assert {(m.uav, m.cmd_id) for m in sent} == {(c.uav, c.cmd_id) for c in record.commands}
    assert all(isinstance(r, CommandAck) and r.accepted for r in replies)
    plans = [unverified_inner(i.message()) for i in items if i.kind == "reply" and i.topic == keys.planner("demo")]
    assert len(plans) == 1 and isinstance(plans[0], MissionPlan) and plans[0] == record.plan
    assert all(bus_bytes(i) is None for i in items if i.kind != "sample")  # a replay never commands a UAV
    frames = len(list(captures(path)))
    assert frames == live["captures"]["planned"]  # every capture's frame reached the ground station

    # replayed at 10x (reliably) under another fleet name onto a live network, where a ground station's log
    # writer records it; the replay's log with the mission's own entries makes the same deliverable
    replayed = tmp_path / "replay.mcap"
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), "again", "gcs") as bus:
        writer = MissionLogWriter(bus, replayed)
        time.sleep(0.5)
        svc = group.start("replay", ["replay", str(path), "--speed", "10", "--as-fleet", "again", "--multilink",
                                     "--reliable", *[a for e in gateway for a in ("--connect", e)]])
        assert svc.wait_for("replayed:", 120), "\n".join(svc.lines)
        wait_until(lambda: writer.counts["frame"] >= frames, 10)
        writer.close()
    again, _ = load_record(replayed, ground=path)
    write_report(again, tmp_path / "replayed", replayed)
    figures = json.loads((tmp_path / "replayed" / "report.json").read_text())
    assert figures["captures"] == live["captures"]  # every capture point imaged again
    assert figures["defects"] == live["defects"]    # the same defect reports, scored the same

    own = _inspection(out)
    assert own[0] is not None and own[1]
    assert _inspection(tmp_path / "replayed") == own  # the mission's deliverable, from the replay
