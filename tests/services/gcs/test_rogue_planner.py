"""A second session holding the planner's identity answers the ground station's plan request late.

The network is ``skynet up`` in its default secure mode (mutual TLS, the certificate ACL, signed commands
and plans, the development key set); the ground station is ``skynet gcs --keys``. The rogue is a
real process that opens a session with the planner's certificate, declares the planner's queryable and
answers 5 s after receiving the request with the attack's plan (a 6 km geofence, every trajectory drifting
420 m east and climbing to 120 m), bound to the request's nonce and scenario:

* with the certificate only (unsigned answer): the answer is refused with its reason, an event says so,
  the real planner's plan is flown and no UAV leaves the scenario's box;
* with the planner's signing key too: two different signed answers to one request, so no plan is taken,
  an event says why, and no UAV takes off.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from services.orchestration import trustmode
from tests.conftest import ROOT
from tests.readiness import launched

FLEET = "rogueplan"

ROGUE = r"""
import sys, time
from protocol import keys
from protocol.bus import Bus, add_bus_args, config_from_args
from protocol.keyset import KeySet
from protocol.messages import PlanRequest
from services.planner.service import answer
from tests.services.gcs.test_preflight import rogue
import argparse

signed = sys.argv[1] == "signed"
parser = argparse.ArgumentParser()
add_bus_args(parser, mode="client")
args = parser.parse_args(sys.argv[2:])
sys.path.insert(0, ".")
signer = KeySet(args.keys, "planner").signer() if signed else None
where = keys.planner(args.fleet)

def handle(req):
    time.sleep(5.0)  # after the real planner
    bad = rogue(answer(req.model_copy(update={"particles": 10, "iterations": 5})))  # bound to the request
    print("rogue answers", req.request_id, flush=True)
    return bad if signer is None else signer.sign(bad, where)

with Bus(config_from_args(args, role="planner"), fleet=args.fleet, name="rogue") as bus:
    bus.serve(where, handle, expect=PlanRequest, ring=4)
    print("rogue up", flush=True)
    while True:
        time.sleep(1)
"""


@pytest.fixture(scope="module")
def network(tmp_path_factory):
    """``skynet up`` (secure by default): yields the gateway's endpoints."""
    folder = tmp_path_factory.mktemp("rogue-planner-network")
    with launched(["up", "--uavs", "3", "--speed", "8", "--fleet", FLEET], cwd=folder) as up:
        endpoints = json.loads((folder / ".skynet" / "network.json").read_text())["endpoints"]
        assert endpoints and all(e.startswith("tls/") for e in endpoints), up.tail(30)
        yield endpoints


def bus_args(endpoints: list[str]) -> list[str]:
    keyset = os.environ[trustmode.KEYS_ENV]  # the session's own key set, the one `skynet up` uses (tests/conftest.py)
    return ["--fleet", FLEET, "--keys", keyset, "--multilink", *[a for e in endpoints for a in ("-e", e)]]


def start_rogue(endpoints: list[str], mode: str, args: list[str] | None = None) -> subprocess.Popen:
    """The rogue planner process (``args``: its bus options, else the secure network's), once its queryable is declared."""
    proc = subprocess.Popen([sys.executable, "-c", ROGUE, mode, *(bus_args(endpoints) if args is None else args)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen = []
    while not seen or "rogue up" not in seen[-1]:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError("the rogue did not start: " + "".join(seen)[-3000:])
        seen.append(line)
    return proc


def fly(endpoints: list[str], out: Path) -> tuple[subprocess.CompletedProcess, dict]:
    proc = subprocess.run([sys.executable, "-m", "services.cli", "gcs", *bus_args(endpoints),
                           "--speed", "8", "--uavs", "3", "--quiet", "--out", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=400)
    assert (out / "record.json").exists(), proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc, json.loads((out / "record.json").read_text())


def outside_box(record: dict, margin: float = 1.0) -> list[tuple[int, list[float]]]:
    lo, hi = record["scenario"]["box"]["lo"], record["scenario"]["box"]["hi"]
    return [(s["msg"]["uav"], s["msg"]["pos"]) for s in record["states"]
            if not all(l - margin <= v <= h + margin for l, v, h in zip(lo, s["msg"]["pos"], hi))]


def stop(proc: subprocess.Popen) -> str:
    proc.kill()
    return proc.communicate()[0] or ""


@pytest.mark.mission
def test_a_rogue_planner_never_steers_the_fleet_out_of_the_scenario(network, tmp_path):
    # the planner's signing key too: two different signed answers, no plan taken, nobody takes off
    rogue = start_rogue(network, "signed")
    try:
        proc, record = fly(network, tmp_path / "conflict")
    finally:
        said = stop(rogue)
    assert "rogue answers 1" in said, said
    why = proc.stdout[-3000:] + proc.stderr[-3000:]
    assert proc.returncode != 0 and not record["success"], why
    # two signed answers: a conflict (on a machine so loaded that the real planner answers more than the
    # settle window after the rogue, the rogue's plan is the only one and leaves the scenario: refused too)
    kinds = {(e["msg"]["kind"], e["msg"]["source"]) for e in record["events"]}
    print("rogue with the planner's key:", record["failures"][0][:160])
    if ("plan-conflict", "gcs") in kinds:
        assert any("2 different plans answered plan request 1" in f for f in record["failures"]), record["failures"]
    else:
        assert any("the plan leaves the scenario: UAV 1 waypoint" in f for f in record["failures"]), (record["failures"], why)
    assert "takeoff" not in record["phases"] and not record["commands"], record["phases"]
    assert not any(s["msg"]["armed"] for s in record["states"])
    assert not outside_box(record)

    # the certificate only: the unsigned answer is refused with its reason, the real plan is flown
    rogue = start_rogue(network, "unsigned")
    try:
        proc, record = fly(network, tmp_path / "unsigned")
    finally:
        said = stop(rogue)
    assert "rogue answers 1" in said, said
    why = proc.stdout[-3000:] + proc.stderr[-3000:]
    refused = [e["msg"]["text"] for e in record["events"] if e["msg"]["kind"] == "plan-refused"]
    assert any("unsigned" in t for t in refused), (refused, why)
    assert proc.returncode == 0 and record["success"], (record["failures"], why)
    plan = record["plan"]
    assert plan["geofence"] == record["scenario"]["box"] and plan["scenario_digest"], plan["geofence"]
    assert max(w["pos"][2] for t in plan["trajectories"] for w in t["waypoints"]) <= record["scenario"]["box"]["hi"][2]
    flown = {s["msg"]["uav"] for s in record["states"] if s["msg"]["armed"]}
    assert flown == {1, 2, 3} and not outside_box(record), outside_box(record)[:5]


# ----------------------------------------------------------------------------- --insecure: no keys, same rules
INSECURE = "rogueins"


def _request_plan(gateway: list[str]):
    """The ground station's plan step alone (no fleet needed), without a key set: (plan or failure, record)."""
    from protocol.bus import Bus, BusConfig
    from protocol.scenario import load_scenario
    from services.gcs.mission import MissionFailed, MissionOptions, MissionRunner

    opts = MissionOptions(uavs=(1, 2, 3), particles=40, iterations=40, plan_timeout_s=60.0)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), INSECURE, "gcs") as bus:
        runner = MissionRunner(bus, load_scenario(), opts)
        try:
            return runner.request_plan(), runner.record
        except MissionFailed as exc:
            return str(exc), runner.record


def test_insecure_unsigned_plans_are_taken_only_inside_the_scenario_and_without_a_second_voice(group, gateway):
    plain = ["--fleet", INSECURE, "--multilink", *[a for e in gateway for a in ("-e", e)]]
    # the rogue alone (no planner): its answer is bound to the request but leaves the scenario's box
    rogue = start_rogue(gateway, "unsigned", plain)
    try:
        outcome, record = _request_plan(gateway)
    finally:
        stop(rogue)
    assert isinstance(outcome, str) and "the plan leaves the scenario: UAV 1 waypoint" in outcome, outcome
    assert any(e.msg.kind == "plan-refused" and "UAV 1 waypoint" in e.msg.text for e in record.events), record.events

    # the real planner and the rogue 5 s later: two different answers, neither taken
    planner = group.start("planner", ["planner", *plain])
    assert planner.wait_ready(30), "\n".join(planner.lines)
    rogue = start_rogue(gateway, "unsigned", plain)
    try:
        outcome, record = _request_plan(gateway)
    finally:
        said = stop(rogue)
    assert "rogue answers 1" in said, said
    assert isinstance(outcome, str) and "2 different plans answered plan request 1" in outcome, outcome
    assert [e.msg.kind for e in record.events] == ["plan-conflict"], record.events

    # the planner alone: its unsigned plan, bound to the request, is taken
    outcome, record = _request_plan(gateway)
    assert not isinstance(outcome, str), outcome
    assert outcome.nonce and outcome.scenario_digest and not record.events
