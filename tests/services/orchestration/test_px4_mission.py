"""The whole 3-UAV mission through the launcher with ``--vehicle mavlink --sim-firmware px4``: every edge picks the
PX4 dialect from its sim autopilot's HEARTBEAT and flies it in OFFBOARD (guided) and in AUTO.MISSION (auto), in the
default secure mode. Same bounds as the ArduCopter missions (tests/services/orchestration/test_mavlink_mission.py)."""

import json
import subprocess
import sys

import pytest

pytest.importorskip("pymavlink", reason="--vehicle mavlink needs the 'mavlink' extra")

pytestmark = pytest.mark.mission  # whole missions: one at a time under xdist (tests/conftest.py)

FORMATION_RMS_BOUND_M = 1.0


@pytest.mark.parametrize("flight", ["guided", "auto"])
def test_mission_with_px4_sim_autopilots(tmp_path, flight):
    out = tmp_path / "report"
    proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--vehicle", "mavlink", "--speed", "8",
                           "--flight", flight, "--sim-firmware", "px4", "--sim-boot-scale", "0.1", "--quiet",
                           "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["success"] and not report["failures"]
    assert all(fig["reached_goal"] for fig in report["uavs"].values()) and len(report["uavs"]) == 3
    assert report["captures"]["planned"] > 0 and report["captures"]["imaged"] == report["captures"]["planned"]
    assert report["formation"]["rms_m"] < FORMATION_RMS_BOUND_M
    log = (out / "services.log").read_text()
    assert all(f"sim-autopilot: uav {i} (system id {i}) as px4" in log for i in (1, 2, 3))
    assert all(f"UAV {i}: autopilot parameters in PX4" in log for i in (1, 2, 3))  # the dialect from the HEARTBEAT
    flown = [f"UAV {i}: flying AUTO.MISSION from mission item" in log for i in (1, 2, 3)]
    assert flown == [flight == "auto"] * 3
    assert "a mode the edge did not command" not in log and "Failsafe: no offboard" not in log
