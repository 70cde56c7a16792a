"""``skynet mission --autopilot uavN=ENDPOINT --home-from-autopilot``: the fleet flies autopilots the user has running.

As a user with three vehicles would: the autopilots (here three ``skynet sim-autopilot`` processes, one per vehicle,
each sending to its own UDP port) run before the launcher and are not its children; each stands at a home other than
the scenario's formation slot. The launcher, in the default secure mode, starts no autopilot of its own, each edge
takes its launch point from its autopilot's HOME_POSITION, and the mission flies as with the launcher's own sim
autopilots (tests/services/orchestration/test_mavlink_mission.py).
"""

from __future__ import annotations

import json
import math
import socket
import subprocess
import sys

import pytest

pytest.importorskip("pymavlink", reason="--vehicle mavlink needs the 'mavlink' extra")

from protocol.scenario import load_scenario  # noqa: E402
from services.orchestration.plan import homes  # noqa: E402
from services.orchestration.process import free_port  # noqa: E402
from services.recording.load import load_record  # noqa: E402
from tests.conftest import fly_mission  # noqa: E402

pytestmark = pytest.mark.mission  # whole missions: one at a time under xdist (tests/conftest.py)

FORMATION_RMS_BOUND_M = 1.0
#: where the vehicles really stand: the scenario's slots moved 6 m west and 3 m south
SHIFT = (-6.0, -3.0, 0.0)
SPEED = 4.0  # at 8x a loaded CI machine once placed captures 5-8.5 m off their points (tolerance 5 m)


def test_mission_flies_the_users_own_autopilots_from_their_homes(tmp_path):
    slots = homes(load_scenario(None), 3)
    real = [tuple(round(s + d, 3) for s, d in zip(slot, SHIFT)) for slot in slots]
    ports = [free_port(socket.SOCK_DGRAM) for _ in range(3)]
    autopilots = []
    try:
        for i, (port, home) in enumerate(zip(ports, real), start=1):
            autopilots.append(subprocess.Popen(
                [sys.executable, "-m", "services.cli", "sim-autopilot", "--uav", str(i), "--port-base",
                 str(port - i + 1), "--home=" + ",".join(map(str, home)), "--speed", str(SPEED), "--boot-scale", "0.1",
                 "--wind", "moderate", "--seed", str(i)],
                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
        run = fly_mission(tmp_path / "report", "--speed", str(SPEED), "--home-from-autopilot",
                          *(x for i, port in enumerate(ports, start=1)
                            for x in ("--autopilot", f"uav{i}=udpin:127.0.0.1:{port}")), timeout=300)
    finally:
        texts = []
        for ap in autopilots:
            ap.terminate()
            try:
                texts.append(ap.communicate(timeout=10)[0])
            except subprocess.TimeoutExpired:
                ap.kill()
                texts.append(ap.communicate()[0])
    run.flown(rms_bound_m=FORMATION_RMS_BOUND_M)
    assert all(f"sim-autopilot: uav {i} (system id {i})" in t for i, t in enumerate(texts, start=1))
    out = run.out
    log = (out / "services.log").read_text()
    assert "sim-autopilot" not in log  # the launcher started no autopilot of its own
    # the default secure mode: mutual TLS, ACL by certificate, every edge as its own identity
    assert "ACL by certificate common name" in log and "INSECURE" not in log
    assert all(f"mutual TLS as uav{i}" in log for i in (1, 2, 3))
    assert all(f"UAV {i}: home from the autopilot" in log for i in (1, 2, 3))
    record, _ = load_record(out / "mission.mcap", caps={})
    for i, home in enumerate(real, start=1):
        grounded = [s.msg for s in record.states if s.msg.uav == i and not s.msg.armed]
        first_armed = next(k for k, s in enumerate(record.states) if s.msg.uav == i and s.msg.armed)
        before = [s.msg for s in record.states[:first_armed] if s.msg.uav == i]
        assert grounded and before, f"UAV {i}: no state on the ground before the flight"
        # where it stood when it took off: its autopilot's home, not the scenario's slot 6.7 m away
        assert math.dist(before[-1].pos, home) < 0.3, (i, before[-1].pos, home)
        assert math.dist(before[-1].pos, slots[i - 1]) > 6.0


def test_one_own_autopilot_beside_the_launchers_sim_ones_in_auto(tmp_path):
    """``--autopilot uav2=...`` alone: UAVs 1 and 3 fly sim autopilots the launcher starts (their homes reckoned from
    the scenario's origin), UAV 2 the one started by hand 6.7 m from its slot; every edge takes its home from its
    autopilot, and the trajectories are flown as uploaded missions in AUTO."""
    slots = homes(load_scenario(None), 3)
    home2 = tuple(round(s + d, 3) for s, d in zip(slots[1], SHIFT))
    port = free_port(socket.SOCK_DGRAM)
    ap = subprocess.Popen([sys.executable, "-m", "services.cli", "sim-autopilot", "--uav", "2", "--port-base",
                           str(port - 1), "--home=" + ",".join(map(str, home2)), "--speed", str(SPEED),
                           "--boot-scale", "0.1", "--wind", "moderate", "--seed", "2"],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out = tmp_path / "report"
        proc = subprocess.run([sys.executable, "-m", "services.cli", "mission", "--speed", str(SPEED),
                               "--home-from-autopilot", "--autopilot", f"uav2=udpin:127.0.0.1:{port}", "--flight",
                               "auto", "--sim-boot-scale", "0.1", "--quiet", "--out", str(out)],
                              capture_output=True, text=True, timeout=300)
    finally:
        ap.terminate()
        try:
            ap.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            ap.kill()
            ap.communicate()
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["success"] and not report["failures"]
    assert report["captures"]["planned"] > 0 and report["captures"]["imaged"] == report["captures"]["planned"]
    log = (out / "services.log").read_text()
    assert [f"sim-autopilot: uav {i} (system id {i})" in log for i in (1, 2, 3)] == [True, False, True]
    assert all(f"UAV {i}: flying AUTO from mission item" in log for i in (1, 2, 3))
    record, _ = load_record(out / "mission.mcap", caps={})
    for i, home in enumerate([slots[0], home2, slots[2]], start=1):
        first_armed = next(k for k, s in enumerate(record.states) if s.msg.uav == i and s.msg.armed)
        before = [s.msg for s in record.states[:first_armed] if s.msg.uav == i]
        assert before and math.dist(before[-1].pos, home) < 0.3, (i, before[-1].pos if before else None, home)
