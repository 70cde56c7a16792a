"""A real mission, recorded by the ground station: the report rebuilt from the MCAP file alone, and
from a replay of it onto the bus, has the live run's figures (states, captures, defects, paths)."""

from __future__ import annotations

import json
import time
from collections import defaultdict

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.messages import CommandAck, DefectReport, MissionPlan, VehicleState
from protocol.signing import unverified_inner
from services.gcs.record import DefectRx, StateRx
from services.gcs.report import summarise
from services.recording.mcap_log import bus_bytes, read
from services.recording.rebuild import rebuild, summary_of, with_lists
from tests.conftest import wait_until

#: figures that use receive times: the recorder's callback runs beside the ground station's, not at
#: the same microsecond, so these differ by about a millisecond and are left out of the comparison
RX_FIGURES = ("latency_ms", "age_ms", "delivery_ms", "last_rx_s", "max_gap_s", "max_gap_ended_s", "rx")


def _strip(d):
    if isinstance(d, dict):
        # reception gaps are receive-time intervals: their number is compared, not their ends
        return {k: (len(v) if k == "gaps" else _strip(v)) for k, v in d.items() if k not in RX_FIGURES and k != "files"}
    if isinstance(d, list):
        return [_strip(v) for v in d]
    return d


def _figures(summary) -> dict:
    return _strip(json.loads(json.dumps(summary.to_dict() if hasattr(summary, "to_dict") else summary)))


@pytest.mark.mission
def test_mission_log_rebuilds_the_report_and_replays(nominal_mission, group, gateway) -> None:
    out = nominal_mission.out
    assert nominal_mission.proc.returncode == 0, nominal_mission.failure()
    live = json.loads((out / "report.json").read_text())
    path = out / "mission.mcap"
    assert path.stat().st_size > 0

    rebuilt = _figures(summarise(rebuild(path)))
    assert rebuilt == _strip(live)
    assert live["captures"]["imaged"] == live["captures"]["planned"] > 0

    # every command the ground station sent is in the log with its acknowledgement, and the plan with it
    items = list(read(path))
    queries = [i for i in items if i.kind == "query" and i.topic.endswith("/cmd")]
    replies = [i.message() for i in items if i.kind == "reply" and i.topic.endswith("/cmd")]
    commands = summary_of(path).record.commands
    assert len(queries) == len(replies) == sum(c.attempts for c in commands) > 0
    sent = [unverified_inner(q.message()) for q in queries]  # signed commands: the log keeps the envelope
    assert {(m.uav, m.cmd_id) for m in sent} == {(c.uav, c.cmd_id) for c in commands}
    assert all(isinstance(r, CommandAck) and r.accepted for r in replies)
    # the planner's answer as received: its signed envelope, the plan inside it the one the mission took
    plans = [unverified_inner(i.message()) for i in items if i.kind == "reply" and i.topic == keys.planner("demo")]
    assert len(plans) == 1 and isinstance(plans[0], MissionPlan) and plans[0] == summary_of(path).record.plan
    assert all(bus_bytes(i) is None for i in items if i.kind != "sample")  # a replay never commands a UAV

    # replay onto the bus at 10x (reliably) under another fleet name; what a listener receives makes the same report
    lists = defaultdict(list)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), "again", "watch") as bus:
        bus.subscribe(keys.state("again", "*"), lambda m, s: lists["states"].append(StateRx(rx=time.time(), msg=m)),
                      expect=VehicleState)
        bus.subscribe(keys.defects("again"), lambda m, s: lists["defects"].append(DefectRx(rx=time.time(), msg=m)),
                      expect=DefectReport)
        time.sleep(0.5)
        svc = group.start("replay", ["replay", str(path), "--speed", "10", "--as-fleet", "again", "--multilink",
                                     "--reliable",
                                     *[a for e in gateway for a in ("--connect", e)]])
        assert svc.wait_for("replayed:", 120), "\n".join(svc.lines)
        logged = rebuild(path)
        wait_until(lambda: len(lists["defects"]) >= len(logged.defects) and len(lists["states"]) >= len(logged.states), 5)
    summary = summary_of(path)
    summary.windows = {k: w for k, w in summary.windows.items() if k in ("states", "defects")}
    record = with_lists(summary, lists, "the replay").model_copy(update={"fleet": "again"})
    again = json.loads(json.dumps(summarise(record).to_dict()))
    assert again["captures"] == live["captures"]  # every capture point imaged again
    assert again["defects"] == live["defects"]    # the same defects, scored the same
    for uav, figs in live["uavs"].items():        # --reliable: every state
        assert again["uavs"][uav]["states"] == figs["states"]
        assert again["uavs"][uav]["reached_goal"] == figs["reached_goal"]
        assert again["uavs"][uav]["path_error_rms_m"] == figs["path_error_rms_m"]
