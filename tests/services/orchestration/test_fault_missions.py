"""Whole missions through the launcher with one scripted fault each ("Faults").

Each test runs ``skynet mission --speed 8 --fault ...`` in a subprocess (real gateway, edges,
planner, detector, proxies) and reads the run's report.json. Times of faults count from the
start of the mission phase; at speed 8 that phase lasts about 10 s of wall time.

Stated bounds (properties of the design, not speed measurements):

* the fleet's telemetry blackout after a gateway kill of ``D`` seconds is at most
  ``D + RESTART_SLACK_S``: the gateway's own start-up (a Python process, under 1.5 s here) plus
  the clients' and peers' reconnect pause (``BusConfig.reconnect_max_s``, 1 s) plus margin;
* an edge killed is seen gone by the others and the ground station within its link lease
  (``EDGE_LEASE_S``, the board's default) plus ``LEASE_SLACK_S``;
* the formation keeps the shape bound of the nominal mission (tests/services/orchestration/test_launcher.py)
  through a SkyNet partition.
"""

import json
import subprocess
import sys

import pytest

from protocol.links import LINK_LEASE_S

pytestmark = pytest.mark.mission  # whole missions: one at a time under xdist (tests/conftest.py)

EDGE_LEASE_S = LINK_LEASE_S  # the board's default lease
LEASE_SLACK_S = 1.0
RESTART_SLACK_S = 3.0
FORMATION_RMS_BOUND_M = 1.0
MAX_CAPTURES_LOST_TO_RESTART = 2  # of 26; the fleet takes about 11 captures while the gateway is down
WALL_LIMIT_S = 240  # a mission that hangs is killed here and fails the test


def _mission(tmp_path, *faults: str) -> tuple[subprocess.CompletedProcess, dict, dict]:
    out = tmp_path / "report"
    cmd = [sys.executable, "-m", "services.cli", "mission", "--speed", "8", "--quiet", "--out", str(out)]
    for f in faults:
        cmd += ["--fault", f]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=WALL_LIMIT_S, check=False)
    assert (out / "report.json").exists(), proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc, json.loads((out / "report.json").read_text()), json.loads((out / "record.json").read_text())


def _landed(record: dict, uav: int) -> bool:
    last = [s["msg"] for s in record["states"] if s["msg"]["uav"] == uav][-1]
    return not last["armed"]


def _explain(proc, report) -> str:
    return f"{report['failures']}\n{json.dumps(report['faults'], indent=1)[:4000]}\n{proc.stderr[-2000:]}"


def test_gateway_killed_and_restarted(tmp_path):
    down_s = 3.0
    proc, report, record = _mission(tmp_path, f"2s kill gateway for {down_s:g}s")
    faults = report["faults"]
    assert [f["action"] for f in faults["faults"]] == ["kill", "restart"], _explain(proc, report)
    # the fleet and the ground station came back: nobody counted lost, the fleet heard again
    (seen,) = faults["seen_again"]
    assert not seen["never"] and seen["fleet_seen_s"] is not None, _explain(proc, report)
    assert seen["blackout_s"] <= down_s + RESTART_SLACK_S, _explain(proc, report)
    assert not faults["still_lost"] and all(x["back_s"] is not None for x in faults["uavs_lost"])
    assert faults["gcs_link"] and all(x["up_s"] is not None for x in faults["gcs_link"])
    # the edges kept flying the formation over SkyNet meanwhile
    assert report["formation"]["rms_m"] < FORMATION_RMS_BOUND_M
    for uav, fig in report["uavs"].items():
        assert fig["reached_goal"], (uav, fig)
        assert _landed(record, int(uav))
    # no command silently lost: every one acknowledged (or listed failed, which would fail here)
    assert faults["commands"]["acknowledged"] == faults["commands"]["sent"] > 0, _explain(proc, report)
    # the captures taken while the gateway was down come back through the cameras' caches, but not
    # always all of them (a frame can be lost for good around the reconnection: 1 of 26, seen in 1 of
    # 5 runs): the issue asks for the fleet and the commands here; coverage is stated, not promised
    # the mission log (the deliverable's input) holds every frame the detector imaged: frames lost while the
    # gateway was down come back from the cameras' caches to the ground station's recorder too
    from services.recording.mcap_log import captures

    logged = {(m.uav, m.capture_id) for m, _ in captures(tmp_path / "report" / "mission.mcap")}
    # (each recovers on its own: a frame lost for good to one of them is possible, as below)
    assert len(logged) >= report["captures"]["imaged"] - 1, (sorted(logged), report["captures"])
    md = (tmp_path / "report" / "report.md").read_text()
    absent = report["captures"]["planned"] - len(logged)
    assert f"(by {len(logged)} of {len(logged)} captures" in md and (
        f"{absent} of the {report['captures']['planned']} planned captures are not among its frames" in md) == (
        absent > 0), md[:2000]
    missing = report["captures"]["planned"] - report["captures"]["imaged"]
    if missing:
        assert all("capture points were not imaged" in f for f in report["failures"]), _explain(proc, report)
        assert missing <= MAX_CAPTURES_LOST_TO_RESTART, _explain(proc, report)
        print(f"\n{missing} capture(s) lost across the gateway restart: {report['failures']}")
    else:
        assert proc.returncode == 0 and report["success"], _explain(proc, report)


def test_one_edge_killed(tmp_path):
    proc, report, record = _mission(tmp_path, "3s kill uav3", "900s kill planner")
    faults = report["faults"]
    assert proc.returncode == 1 and not report["success"]  # ended cleanly, did not hang (timeout above)
    assert any(f.startswith("UAV 3 lost at mission t=") and "capture points not imaged" in f
               for f in report["failures"]), report["failures"]
    # a fault the mission ended before is a failure of the run asked for, not a silent omission
    assert "never injected, the mission ended first: 900s kill planner" in report["failures"], report["failures"]
    assert faults["not_injected"] == ["900s kill planner"], faults
    assert len(report["failures"]) == 2, report["failures"]  # the others did their part
    (kill,) = [f for f in faults["faults"] if f["action"] == "kill"]
    # the ground station and both other edges saw it gone within its lease
    (gone,) = [x for x in faults["uavs_lost"] if x["uav"] == 3]
    assert gone["gone_s"] - kill["t_s"] <= EDGE_LEASE_S + LEASE_SLACK_S, gone
    assert gone["lost_s"] is not None and gone["back_s"] is None and faults["still_lost"] == [3]
    for uav in (1, 2):
        seen = [x for x in faults["skynet"] if x["uav"] == uav and x["kind"] == "neighbour-lost" and x["neighbour"] == 3]
        assert seen and seen[0]["t_s"] - kill["t_s"] <= EDGE_LEASE_S + LEASE_SLACK_S, (uav, faults["skynet"])
    # the remaining UAVs kept their slots, reached their goals, imaged their captures and landed
    for uav in (1, 2):
        fig = report["uavs"][str(uav)]
        assert fig["reached_goal"] and fig["captures_imaged"] == fig["captures_planned"], (uav, fig)
        assert _landed(record, uav)
    # nothing silently lost: UAV 3's Land is recorded as not sent, everything else acknowledged
    failed = faults["commands"]["failed"]
    assert failed and all(c["uav"] == 3 and "lost" in c["reason"] for c in failed), failed
    md = (tmp_path / "report" / "report.md").read_text()
    assert "## Faults and recovery" in md and "UAV 3" in md
    assert "Scheduled and never injected (the mission ended first): 900s kill planner." in md


def test_uplinks_cut_longer_than_the_failsafe(tmp_path):
    proc, report, record = _mission(tmp_path, "1s cut uplinks for 8s")  # the edges' failsafe: 5 s, hold
    faults = report["faults"]
    # every UAV held (failsafe) and was resumed once the link and the ground station were back
    assert {f["uav"] for f in faults["failsafes"]} == {1, 2, 3}, _explain(proc, report)
    resumed = {r["uav"] for r in faults["resumes"] if r["ok"]}
    assert resumed == {1, 2, 3}, _explain(proc, report)
    (restore,) = [f for f in faults["faults"] if f["action"] == "restore"]
    assert all(r["t_s"] >= restore["t_s"] for r in faults["resumes"])
    held = [s["msg"] for s in record["states"] if s["msg"]["mode"] == "hold" and 0 < s["msg"]["progress"] < 1]
    assert {m["uav"] for m in held} == {1, 2, 3}  # they were seen holding mid-mission
    assert proc.returncode == 0 and report["success"], _explain(proc, report)
    assert report["captures"]["imaged"] == report["captures"]["planned"] > 0
    assert faults["commands"]["acknowledged"] == faults["commands"]["sent"]


def test_skynet_partition_falls_back_to_planned_slots_and_recovers(tmp_path):
    proc, report, record = _mission(tmp_path, "1s partition uav1-uav2 for 4s")
    faults = report["faults"]
    (part,) = [f for f in faults["faults"] if f["action"] == "partition"]
    (heal,) = [f for f in faults["faults"] if f["action"] == "heal"]
    sky = faults["skynet"]

    def during(uav, other, kinds):
        return [x for x in sky if x["uav"] == uav and x["neighbour"] == other and x["kind"] in kinds
                and part["t_s"] <= x["t_s"] <= heal["t_s"]]

    # both ends stopped hearing each other (stale: formation keeping without it), UAV 3 heard both
    assert during(1, 2, ("neighbour-stale", "neighbour-lost")) and during(2, 1, ("neighbour-stale", "neighbour-lost")), sky
    assert not [x for x in sky if x["uav"] == 3 or x["neighbour"] == 3], sky
    # and heard each other again after the heal
    after = [s["msg"] for s in record["states"] if s["msg"]["uav"] in (1, 2)
             and s["rx"] - record["phases"]["mission"] > heal["t_s"] + 2.0 and s["msg"]["mode"] == "mission"]
    assert after and all(m["neighbours"] == 2 for m in after[-10:]), [m["neighbours"] for m in after[-10:]]
    assert report["formation"]["rms_m"] < FORMATION_RMS_BOUND_M, report["formation"]
    assert proc.returncode == 0 and report["success"], _explain(proc, report)
