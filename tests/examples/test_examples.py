"""examples/ as a user runs them: each script a subprocess against a real network started by ``skynet up`` in the
default secure mode (mutual TLS, access control by certificate, signed commands), found through the network's
description (.skynet/network.json) in the working folder, as the scripts' docstrings say."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import ROOT
from tests.readiness import interrupt, launched

EXAMPLES = ROOT / "examples"
BUS_EXAMPLES = ["fleet_states.py", "command_uav.py", "request_plan.py", "watch_defects.py"]
STATE_LINE = re.compile(r"^uav (\d+)  pos \(\s*-?[\d.]+,\s*-?[\d.]+,\s*-?[\d.]+\) m  mode (\w+)\s+battery\s+\d+%$")
REPORT_LINE = re.compile(r"^uav (\d+) capture (\d+): (\d+) defects \([\d.]+% of the frame")


@dataclass(frozen=True)
class Network:
    """A running ``skynet up``: the folder it runs in (its description is there) and the description."""

    folder: Path
    desc: dict
    lines: list[str]


def run_example(name: str, *argv: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    """``python examples/NAME ARGV...`` in ``cwd``; never a traceback, whatever the outcome."""
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), *argv], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr[-3000:]
    return proc


@pytest.fixture(scope="module")
def network(tmp_path_factory, dev_keys):
    """``skynet up --speed 4`` in a folder of its own, secure by default with the session's development key set
    (``$SKYNET_KEYS``, tests/conftest.py), once for the module; stopped with Ctrl-C after it."""
    folder = tmp_path_factory.mktemp("examples-network")
    with launched(["up", "--speed", "4", "--fleet", "examples"], cwd=folder) as up:
        desc = json.loads((folder / ".skynet" / "network.json").read_text())
        assert desc["tls"] and desc["keys"] == str(Path(dev_keys).resolve()), desc
        yield Network(folder, desc, up.lines)


def test_fleet_states_prints_every_uavs_state(network):
    proc = run_example("fleet_states.py", "--count", "30", "--duration-s", "60", cwd=network.folder)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    found = [STATE_LINE.match(line) for line in lines]
    assert len(lines) == 30 and all(found), proc.stdout
    assert {int(m.group(1)) for m in found} == {1, 2, 3}, proc.stdout
    assert {m.group(2) for m in found} == {"idle"}, proc.stdout  # no mission flies yet


def test_fleet_states_shows_neither_garbage_nor_a_state_speaking_for_another_uav(network, dev_keys):
    """A node with a valid key (UAV 2's certificate) puts garbage and states that claim to be UAV 1 on its own key:
    the example neither crashes nor shows them, and goes on with the real states."""
    import time

    from protocol import codec, keys
    from protocol.bus import Bus, BusConfig
    from protocol.keyset import KeySet
    from protocol.links import TELEMETRY
    from protocol.messages import Mode, VehicleState

    fleet, ks = network.desc["fleet"], KeySet(dev_keys, "uav2")
    config = BusConfig(mode="client", connect=network.desc["endpoints"], multilink=True, tls_ca=str(ks.tls_ca),
                       tls_cert=str(ks.tls_cert), tls_key=str(ks.tls_key))
    forged = VehicleState(uav=1, seq=0, t=0.0, stamp=time.time(), pos=(-77.7, -77.7, 7.7), vel=(0, 0, 0),
                          att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.HOLD, armed=True)
    watcher = subprocess.Popen([sys.executable, str(EXAMPLES / "fleet_states.py"), "--duration-s", "8"],
                               cwd=network.folder, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with Bus(config, fleet, "rogue") as rogue:
            pub = rogue.publisher(keys.state(fleet, 2), TELEMETRY)
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:  # 50 ms apart: the gateway's ingress keeps one state per 5 ms a face
                pub.put_bytes(b"\xc1" * 64)  # not msgpack
                time.sleep(0.05)
                pub.put_bytes(codec.encode(forged))
                time.sleep(0.05)
        out, err = watcher.communicate(timeout=60)
    finally:
        watcher.kill()
    assert watcher.returncode == 0 and "Traceback" not in err, err[-3000:]
    found = [STATE_LINE.match(line) for line in out.splitlines()]
    assert found and all(found), out[-3000:]
    shown = {int(m.group(1)) for m in found if m}
    forged_shown = "-77.70" in out
    assert not forged_shown and shown == {1, 2, 3}, out[-3000:]


@pytest.mark.parametrize("name", ["fleet_states.py", "watch_defects.py"])
def test_ctrl_c_ends_a_subscriber_cleanly(network, name):
    import time

    proc = subprocess.Popen([sys.executable, str(EXAMPLES / name)], cwd=network.folder, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        if name == "fleet_states.py":
            assert proc.stdout.readline().startswith("uav "), proc.stderr.read()[-3000:]  # attached and printing
        else:
            time.sleep(5)  # no mission: nothing to print; attached by now
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0 and err == "", err[-3000:]


def test_a_key_set_that_is_not_one_is_said_in_one_line(network, tmp_path):
    proc = run_example("fleet_states.py", "--keys", str(tmp_path), "--count", "1", cwd=network.folder)
    assert proc.returncode == 1 and proc.stdout == "", proc.stdout
    assert proc.stderr.count("\n") == 1 and "not a key set (no ca.pem)" in proc.stderr, proc.stderr


def test_command_uav_is_answered_by_the_vehicle_after_its_signature(network):
    """A grounded UAV refuses to hold: the refusal is the vehicle's (its mode), so the signed envelope passed the
    UAV's verification (a trust refusal reads "refused: trust: ...")."""
    proc = run_example("command_uav.py", "--uav", "1", "--command", "hold", cwd=network.folder)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert re.fullmatch(r"uav 1 acknowledged hold #\d+ in \d+ ms: refused: cannot hold in mode idle .*\n",
                        proc.stdout), proc.stdout
    nobody = run_example("command_uav.py", "--uav", "9", cwd=network.folder)
    assert nobody.returncode == 1 and "uav 9: no acknowledgement of hold" in nobody.stdout, nobody.stdout


def test_request_plan_gives_a_signed_plan_for_three_uavs_inside_the_scenario(network):
    proc = run_example("request_plan.py", cwd=network.folder)
    assert proc.returncode == 0, proc.stdout + proc.stderr[-3000:]
    out = proc.stdout
    assert "signature verified" in out and "refused" not in out, out
    counts = {int(u): int(n) for u, n in re.findall(r"^uav (\d+): (\d+) waypoints$", out, re.M)}
    assert set(counts) == {1, 2, 3} and min(counts.values()) > 1, out
    assert out.rstrip().endswith("check against the scenario: ok"), out


@pytest.mark.mission
def test_watch_defects_and_a_hold_during_a_mission(network, tmp_path):
    """A ground station's mission against the running network (``skynet gcs`` on the network's gateway,
    with the key set's gcs identity); watch_defects prints the detector's reports as the captures arrive, and a
    hold commanded mid-flight is accepted."""
    desc = network.desc
    argv = ["gcs", "--quiet", "--speed", "4", "--fleet", desc["fleet"], "--keys", desc["keys"],
            "--multilink", *[a for e in desc["endpoints"] for a in ("-e", e)]]
    with open(tmp_path / "gcs.log", "w") as log:
        gcs = subprocess.Popen([sys.executable, "-m", "services.cli", *argv], cwd=tmp_path, stdout=log,
                               stderr=subprocess.STDOUT)
    try:
        watch = run_example("watch_defects.py", "--count", "3", "--duration-s", "240", cwd=network.folder, timeout=300)
        said = watch.stdout + (tmp_path / "gcs.log").read_text()[-3000:]
        assert watch.returncode == 0, said
        reports = [REPORT_LINE.match(line) for line in watch.stdout.splitlines()]
        assert len(reports) == 3 and all(reports), said
        assert {int(m.group(1)) for m in reports} <= {1, 2, 3}, said
        hold = run_example("command_uav.py", "--uav", "2", "--command", "hold", cwd=network.folder)
        assert hold.returncode == 0 and re.fullmatch(r"uav 2 acknowledged hold #\d+ in \d+ ms: accepted\n",
                                                     hold.stdout), hold.stdout + hold.stderr
    finally:
        interrupt(gcs)


@pytest.mark.parametrize("name", BUS_EXAMPLES)
def test_without_a_network_each_says_so_in_one_line(name, tmp_path):
    proc = run_example(name, cwd=tmp_path, timeout=60)
    assert proc.returncode == 1 and proc.stdout == "", proc.stdout
    assert proc.stderr.count("\n") == 1 and f"{name}: error: no network running here" in proc.stderr, proc.stderr


@pytest.mark.parametrize("name", [*BUS_EXAMPLES, "read_mcap.py"])
def test_each_is_short_and_says_how_to_run_it(name):
    text = (EXAMPLES / name).read_text()
    assert len(text.splitlines()) <= 70, name
    help_ = run_example(name, "--help", cwd=ROOT, timeout=60)
    assert help_.returncode == 0 and "usage:" in help_.stdout, help_.stderr
    if name != "read_mcap.py":
        assert "--network FILE" in help_.stdout and "--keys DIR" in help_.stdout and "(default:" in help_.stdout
    assert name in (EXAMPLES / "README.md").read_text()
