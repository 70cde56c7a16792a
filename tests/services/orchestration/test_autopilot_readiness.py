"""Whole missions through the launcher with ``--vehicle mavlink``, in the default secure mode, against sim
autopilots that take time to be ready (as ArduCopter's firmware: home after its EKF origin, GUIDED and
AUTO only once its EKF uses GPS): the ground station waits for every autopilot before any takeoff,
and refuses naming the UAV and the autopilot's own reason when one never becomes ready.
"""

import json
import subprocess
import sys

import pytest

pytest.importorskip("pymavlink", reason="--vehicle mavlink needs the 'mavlink' extra")

pytestmark = pytest.mark.mission  # whole missions: one at a time under xdist (tests/conftest.py)


def mission(tmp_path, *args: str) -> tuple[subprocess.CompletedProcess, dict, str]:
    out = tmp_path / "report"
    proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--vehicle", "mavlink", "--speed", "8",
                           "--quiet", "--out", str(out), *args], capture_output=True, text=True, timeout=300)
    report = json.loads((out / "report.json").read_text()) if (out / "report.json").exists() else {}
    return proc, report, proc.stdout + proc.stderr


def test_the_ground_station_waits_for_autopilots_still_starting_and_the_mission_succeeds(slow_boot_guided_mission):
    # GUIDED allowed 42 x 3 = 126 simulated s after power-on: ~16 wall s at x8, later than the plan is ready; the
    # run is shared with the MAVLink GUIDED mission test (tests/conftest.py)
    run = slow_boot_guided_mission
    proc, text = run.proc, run.proc.stdout + run.proc.stderr
    assert (run.out / "report.json").exists(), text[-3000:]
    report = run.report()
    assert proc.returncode == 0, text[-3000:]
    assert report["success"] and not report["failures"]
    assert report["captures"]["imaged"] == report["captures"]["planned"] > 0
    assert "waiting for the autopilots" in text, text[-3000:]  # it did wait (without it: "arm refused")


def test_an_autopilot_that_never_becomes_ready_is_refused_before_any_takeoff_naming_the_uav_and_reason(tmp_path):
    # past BOOT after 40 simulated s (5 wall s at x8), no home before 400 s: never ready within the 8 s wait
    proc, report, text = mission(tmp_path, "--sim-boot-scale", "20", "--ready-timeout-s", "8")
    assert proc.returncode != 0
    (failure,) = [f for f in report["failures"] if "refused before takeoff" in f]
    assert "autopilot not ready" in failure and all(f"UAV {u}:" in failure for u in (1, 2, 3)), failure
    assert "waiting for home" in failure or "no home position" in failure, failure  # the autopilot's own words
    assert "takeoff" not in report.get("phases", {"takeoff": 0}) or "phase: takeoff" not in text
