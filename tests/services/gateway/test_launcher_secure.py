"""``skynet up --secure``: the launcher's network with generated credentials and the gateway's ACL."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.links import TELEMETRY
from protocol.messages import VehicleState
from protocol.acl import read_users
from tests.conftest import wait_until

FLEET = "secup"


def test_up_secure_runs_an_authenticated_network_and_removes_its_credentials():
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "up", "--secure", "--uavs", "2", "--speed", "4",
                             "--fleet", FLEET], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    endpoints, folder, lines = None, None, []
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and folder is None:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "network up: gateway at" in line:
                endpoints = line.split("gateway at ")[1].split(";")[0].split()
            if "users file (passwords) in" in line:
                folder = Path(line.split(" in ")[-1].strip())
        assert endpoints and folder, "".join(lines[-30:])
        passwords = read_users(folder / "users.txt")
        assert set(passwords) == {"gcs", "planner", "detector", "uav1", "uav2"}
        assert not any(p in "".join(lines) for p in passwords.values())  # never printed
        with pytest.raises(zenoh.ZError):  # no credentials, no entry
            Bus(BusConfig(mode="client", connect=endpoints, multilink=True, connect_timeout_s=2.0), FLEET, "anon")
        states: dict[int, VehicleState] = {}
        cfg = BusConfig(mode="client", connect=endpoints, multilink=True, user="gcs", password=passwords["gcs"])
        with Bus(cfg, FLEET, "gcs") as gcs:
            gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: states.__setitem__(m.uav, m), expect=VehicleState,
                          link=TELEMETRY)
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not (
                    {1, 2} <= set(states) and all(states[u].neighbours == 1 for u in (1, 2))):
                time.sleep(0.1)
            rcus = {keys.rcu_alive(FLEET, "planner"), keys.rcu_alive(FLEET, "detector")}
            # the RCUs may come up after the UAVs have meshed (the detector starts its worker processes first)
            wait_until(lambda: rcus <= set(gcs.alive(keys.fleet_all(FLEET))), 30)
            alive = set(gcs.alive(keys.fleet_all(FLEET)))
        assert {1, 2} <= set(states) and all(states[u].neighbours == 1 for u in (1, 2)), states  # mesh + gateway
        assert rcus <= alive
    finally:
        proc.send_signal(signal.SIGINT)
        rest = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, rest[-2000:]
    assert folder is not None and not folder.exists()
