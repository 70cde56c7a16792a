"""A real mission, recorded by the ground station: the report rebuilt from the MCAP file alone, and
from a replay of it onto the bus, has the live run's figures (states, captures, defects, paths)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.messages import DefectReport, VehicleState
from services.gcs.record import DefectRx, StateRx
from services.gcs.report import summarise
from services.recording.rebuild import rebuild, summary_of
from tests.conftest import wait_until

ROOT = Path(__file__).resolve().parents[3]
#: figures that use receive times: the recorder's callback runs beside the ground station's, not at
#: the same microsecond, so these differ by about a millisecond and are left out of the comparison
RX_FIGURES = ("latency_ms", "age_ms", "delivery_ms", "last_rx_s", "max_gap_s", "max_gap_ended_s", "rx")


def _strip(d):
    if isinstance(d, dict):
        return {k: _strip(v) for k, v in d.items() if k not in RX_FIGURES and k != "files"}
    if isinstance(d, list):
        return [_strip(v) for v in d]
    return d


def _figures(summary) -> dict:
    return _strip(json.loads(json.dumps(summary.to_dict() if hasattr(summary, "to_dict") else summary)))


def test_mission_log_rebuilds_the_report_and_replays(group, gateway, tmp_path: Path) -> None:
    out = tmp_path / "m"
    proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--speed", "8", "--quiet", "--out", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    live = json.loads((out / "report.json").read_text())
    path = out / "mission.mcap"
    assert path.stat().st_size > 0

    rebuilt = _figures(summarise(rebuild(path)))
    assert rebuilt == _strip(live)
    assert live["captures"]["imaged"] == live["captures"]["planned"] > 0

    # replay onto the bus at 10x under another fleet name; what a listener receives makes the same report
    lists = defaultdict(list)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), "again", "watch") as bus:
        bus.subscribe(keys.state("again", "*"), lambda m, s: lists["states"].append(StateRx(rx=time.time(), msg=m)),
                      expect=VehicleState)
        bus.subscribe(keys.defects("again"), lambda m, s: lists["defects"].append(DefectRx(rx=time.time(), msg=m)),
                      expect=DefectReport)
        time.sleep(0.5)
        svc = group.start("replay", ["replay", str(path), "--speed", "10", "--as-fleet", "again", "--multilink",
                                     *[a for e in gateway for a in ("--connect", e)]])
        assert svc.wait_for("replayed:", 120), "\n".join(svc.lines)
        wait_until(lambda: len(lists["defects"]) >= len(rebuild(path).defects), 5)
    summary = summary_of(path)
    record = summary.record.model_copy(update={"fleet": "again", "states": lists["states"],
                                               "defects": lists["defects"]})
    again = json.loads(json.dumps(summarise(record).to_dict()))
    assert again["captures"] == live["captures"]  # every capture point imaged again
    assert again["defects"] == live["defects"]    # the same defects, scored the same
    for uav, figs in live["uavs"].items():        # telemetry is best-effort: nearly every state
        assert again["uavs"][uav]["states"] >= 0.95 * figs["states"], (uav, again["uavs"][uav]["states"], figs["states"])
        assert again["uavs"][uav]["reached_goal"] == figs["reached_goal"]
