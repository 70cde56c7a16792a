"""The whole system through the launcher at an accelerated clock (issue 6)."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest

#: stated bounds of the end-to-end mission (README, "Mission")
FORMATION_RMS_BOUND_M = 1.0
DEFECT_RECALL_BOUND = 0.7
PLOTS = ["trajectories.png", "altitudes.png", "path_error.png", "formation_error.png", "convergence.png",
         "defects_map.png", "links.png"]


def test_mission_through_the_launcher(tmp_path):
    out = tmp_path / "report"
    proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--speed", "8", "--quiet", "--out", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["success"] and not report["failures"]
    assert set(report["uavs"]) == {"1", "2", "3"}
    for uav, fig in report["uavs"].items():
        assert fig["reached_goal"], (uav, fig)
    assert report["formation"]["rms_m"] < FORMATION_RMS_BOUND_M
    assert report["captures"]["planned"] > 0 and report["captures"]["imaged"] == report["captures"]["planned"]
    assert report["defects"]["n_truth"] > 0 and report["defects"]["recall"] >= DEFECT_RECALL_BOUND
    for name in ["report.md", "record.json", "report.json", *PLOTS]:
        assert (out / name).stat().st_size > 0, name
    md = (out / "report.md").read_text()
    assert all(f"({p})" in md for p in PLOTS)


def test_up_starts_everything_and_ctrl_c_leaves_no_orphans():
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "up", "--speed", "4"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines = []
    deadline = time.monotonic() + 60
    names = {"gateway", "uav1", "uav2", "uav3", "planner", "detector"}
    seen = set()
    try:
        while time.monotonic() < deadline and not {"network-up", *names} <= seen:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "network up" in line:
                seen.add("network-up")
            for n in names:
                if line.strip().startswith(f"{n} |") and ("up" in line):
                    seen.add(n)
        assert {"network-up", *names} <= seen, "".join(lines[-40:])
        pids = [int(p) for p in subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True,
                                               text=True).stdout.split()]
        assert len(pids) == 6
    finally:
        proc.send_signal(signal.SIGINT)
        rest = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, rest[-2000:]
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)
    assert "shutting down" in rest
