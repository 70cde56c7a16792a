"""The board over the real bus: three edges and the gateway in processes."""

import select
import time

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.links import TELEMETRY
from protocol.messages import (
    CommandAck,
    Event,
    Hold,
    Mode,
    Resume,
    Takeoff,
    Trajectory,
    UploadTrajectory,
    VehicleState,
    Waypoint,
)
from tests.conftest import spawn_node
from tests.conftest import wait_until as _wait

FLEET = "test"
HOMES = {1: "10,10,0", 2: "14,10,0", 3: "6,10,0"}


def heartbeats(gateway):
    """A ground station's heartbeat (5 Hz) in its own process, returned once an edge hears it.

    Under load the process takes seconds to start; an edge that never heard a heartbeat has no
    failsafe armed (as ArduPilot's FS_GCS), so a test that kills it too early would wait in vain.
    """
    node = spawn_node(f"""
import time
from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.links import COMMAND
from protocol.messages import Heartbeat
with Bus(BusConfig(mode="client", connect={gateway!r}, multilink=True), "{FLEET}", "hb") as bus:
    pub = bus.publisher(keys.heartbeat("{FLEET}"), COMMAND)
    told = False
    for i in range(100000):
        pub.put(Heartbeat(seq=i, stamp=time.time()))
        if not told and i >= 10 and pub.matching():
            print("heard", flush=True)
            told = True
        time.sleep(0.2)
""")
    ready, _, _ = select.select([node.stdout], [], [], 60)
    line = node.stdout.readline() if ready else ""
    if line.strip() != "heard":
        node.kill()
        raise AssertionError(f"the heartbeat process never reached an edge: {line!r}")
    return node


@pytest.fixture
def fleet(group, gateway):
    edges = {}
    for uav, home in HOMES.items():
        edges[uav] = group.start(f"uav{uav}", [
            "edge", "--uav", str(uav), "--fleet", FLEET, "--multilink", "--camera", "none",
            *[a for e in gateway for a in ("--connect", e)], "--listen", "tcp/127.0.0.1:0",
            "--home", home, "--speed", "4", "--failsafe-timeout-s", "2", "--geofence", "0,0,0,100,100,40"])
    for svc in edges.values():
        assert svc.wait_ready(30), "\n".join(svc.lines)
    return edges


def test_board_state_sharing_commands_failsafe_and_liveliness(fleet, gateway):
    states: dict[int, VehicleState] = {}
    events: list[Event] = []
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "gcs") as gcs:
        gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: states.__setitem__(m.uav, m), expect=VehicleState,
                      link=TELEMETRY)
        gcs.subscribe(keys.all_events(FLEET), lambda m, s: events.append(m), expect=Event)

        # SkyNet: every edge hears the two others
        assert _wait(lambda: len(states) == 3 and all(s.neighbours == 2 for s in states.values()), 30), states

        # a command is acknowledged; an invalid one is refused with its reason and never reaches the vehicle
        ack = gcs.request(keys.cmd(FLEET, 1), Takeoff(uav=1, cmd_id=1, altitude=5), expect=CommandAck)
        assert ack.ok and ack.message.accepted, ack
        early = gcs.request(keys.cmd(FLEET, 2), Hold(uav=2, cmd_id=2), expect=CommandAck)
        assert early.ok and not early.message.accepted and early.message.reason
        outside = Trajectory(uav=2, waypoints=[Waypoint(t=0, pos=(10, 10, 5)), Waypoint(t=30, pos=(10, 150, 5))])
        refused = gcs.request(keys.cmd(FLEET, 2), UploadTrajectory(uav=2, cmd_id=3, trajectory=outside), expect=CommandAck)
        assert refused.ok and not refused.message.accepted
        assert "geofence" in refused.message.reason
        too_fast = Trajectory(uav=2, waypoints=[Waypoint(t=0, pos=(10, 10, 5)), Waypoint(t=1, pos=(10, 90, 5))])
        fast = gcs.request(keys.cmd(FLEET, 2), UploadTrajectory(uav=2, cmd_id=4, trajectory=too_fast), expect=CommandAck)
        assert fast.ok and not fast.message.accepted and "m/s" in fast.message.reason
        wrong = gcs.request(keys.cmd(FLEET, 2), Takeoff(uav=3, cmd_id=5, altitude=5), expect=CommandAck)
        assert wrong.ok and not wrong.message.accepted and "addressed to UAV 3" in wrong.message.reason
        assert states[2].mode == Mode.IDLE
        assert _wait(lambda: states[1].mode == Mode.HOLD and states[1].pos[2] > 4.5, 30), states[1]

        # failsafe: the ground-station side sends heartbeats, then dies
        hb = heartbeats(gateway)
        try:
            time.sleep(2.0)
            assert not any(e.kind == "failsafe" for e in events)
        finally:
            hb.kill()
            hb.communicate()
        assert _wait(lambda: any(e.kind == "failsafe" for e in events), 10), events
        fs = next(e for e in events if e.kind == "failsafe")
        assert fs.source == "uav/1" and fs.data["action"] == "hold"
        assert fs.data["silent_s"] < 2.0 + 0.5  # noticed within the timeout (plus one control tick)

        # killing one edge is noticed by the others through liveliness
        fleet[3].proc.kill()
        assert _wait(lambda: {e.source for e in events if e.kind == "neighbour-lost" and e.data.get("neighbour") == 3}
                     == {"uav/1", "uav/2"}, 15), [e for e in events if e.kind.startswith("neighbour")]
        assert _wait(lambda: states[1].neighbours == 1, 10)


def test_imagery_cache_option_defaults_to_the_runtime_cache_and_refuses_negatives(capsys):
    from edge.board import build_parser
    from edge.config import IMAGERY_CACHE_FRAMES

    parser = build_parser()
    assert parser.parse_args(["--uav", "1"]).imagery_cache == IMAGERY_CACHE_FRAMES
    assert parser.parse_args(["--uav", "1", "--imagery-cache", "0"]).imagery_cache == 0
    for bad in ("-1", "many"):
        with pytest.raises(SystemExit) as exc:
            parser.parse_args(["--uav", "1", "--imagery-cache", bad])
        assert exc.value.code == 2
    assert "--imagery-cache" in capsys.readouterr().err


def test_failsafe_escalates_to_rtl_refuses_a_stale_resume_and_the_battery_failsafe_returns(group, gateway):
    """with the ground station killed a UAV used to hold for ever, and a Resume that overtook the
    first heartbeat resumed a UAV that failed safe again at once. Now the hold escalates to RTL after
    --failsafe-escalate-after-s (here 2 s) and the UAV comes down; a Resume with no fresh heartbeat is refused.
    A second UAV with a short battery (--endurance-s) returns to launch when it runs low."""
    common = ["--fleet", FLEET, "--multilink", "--camera", "none", *[a for e in gateway for a in ("--connect", e)],
              "--listen", "tcp/127.0.0.1:0", "--speed", "4", "--geofence", "0,0,0,100,100,40"]
    e1 = group.start("uav1", ["edge", "--uav", "1", "--home", "10,10,0", "--failsafe-timeout-s", "1",
                              "--failsafe-escalate-after-s", "2", *common])
    e2 = group.start("uav2", ["edge", "--uav", "2", "--home", "20,10,0", "--endurance-s", "60",
                              "--battery-low", "0.8", *common])
    for svc in (e1, e2):
        assert svc.wait_ready(30), "\n".join(svc.lines)
    states: dict[int, VehicleState] = {}
    events: list[Event] = []
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "gcs") as gcs:
        gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: states.__setitem__(m.uav, m), expect=VehicleState,
                      link=TELEMETRY)
        gcs.subscribe(keys.all_events(FLEET), lambda m, s: events.append(m), expect=Event)
        assert _wait(lambda: len(states) == 2, 30)
        hb = heartbeats(gateway)
        try:
            for uav in (1, 2):
                ack = gcs.request(keys.cmd(FLEET, uav), Takeoff(uav=uav, cmd_id=1, altitude=5), expect=CommandAck)
                assert ack.ok and ack.message.accepted, ack
            assert _wait(lambda: states[1].mode == Mode.HOLD and states[1].pos[2] > 4.5, 30), states[1]
        finally:
            hb.kill()  # the ground station dies
            hb.communicate()
        assert _wait(lambda: any(e.kind == "failsafe" and e.source == "uav/1" for e in events), 10), events
        stale = gcs.request(keys.cmd(FLEET, 1), Resume(uav=1, cmd_id=2), expect=CommandAck)
        assert stale.ok and not stale.message.accepted and "no fresh" in stale.message.reason
        assert _wait(lambda: any(e.kind == "failsafe-escalated" and e.source == "uav/1" for e in events), 10), events
        esc = next(e for e in events if e.kind == "failsafe-escalated")
        assert esc.data["action"] == "rtl"
        assert _wait(lambda: not states[1].armed, 60), states[1]  # back on the ground
        assert _wait(lambda: any(e.kind == "battery-failsafe" and e.source == "uav/2" for e in events), 30), \
            (states.get(2), events)
        bat = next(e for e in events if e.kind == "battery-failsafe")
        assert bat.data["action"] == "rtl" and bat.data["battery"] <= 0.8
    assert e1.alive() and e2.alive()


def test_an_edge_hears_only_its_formation(group, gateway):
    """UAVs 1, 2 and 4 of a fleet flown as formations of three (1-3, 4-6): UAV 1 shares
    state with UAV 2 only, UAV 4 with nobody, although every edge reaches every other."""
    for uav, home in {1: "10,10,0", 2: "14,10,0", 4: "18,10,0"}.items():
        svc = group.start(f"uav{uav}", [
            "edge", "--uav", str(uav), "--fleet", FLEET, "--multilink", "--camera", "none",
            *[a for e in gateway for a in ("--connect", e)], "--listen", "tcp/127.0.0.1:0", "--home", home])
        assert svc.wait_ready(30), "\n".join(svc.lines)
    states: dict[int, VehicleState] = {}
    events: list[Event] = []
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "gcs") as gcs:
        gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: states.__setitem__(m.uav, m), expect=VehicleState,
                      link=TELEMETRY)
        gcs.subscribe(keys.all_events(FLEET), lambda m, s: events.append(m), expect=Event)
        assert _wait(lambda: len(states) == 3 and states[1].neighbours == 1 and states[2].neighbours == 1, 30), states
        time.sleep(1.5)  # long enough for a state of UAV 4 to have reached UAV 1 had it subscribed
        assert states[1].neighbours == 1 and states[2].neighbours == 1 and states[4].neighbours == 0, states
        joined = {(e.source, e.data.get("neighbour")) for e in events if e.kind == "neighbour-up"}
        assert not {pair for pair in joined if 4 in (pair[1], int(pair[0].split("/")[1]))}, joined


def test_nice_option_takes_a_niceness_and_refuses_the_rest():
    import argparse

    from edge.board import build_parser
    from edge.config import niceness

    assert niceness("0") == 0 and niceness("19") == 19
    for bad in ("-1", "20", "x", "1.5"):
        with pytest.raises(argparse.ArgumentTypeError):
            niceness(bad)
    assert build_parser().parse_args(["--uav", "2", "--nice", "5"]).nice == 5
    assert build_parser().parse_args(["--uav", "2"]).nice == 0


def test_yield_cpu_lowers_the_priority_of_the_process_and_of_its_session_group():
    """In a session of its own (as the launcher starts an edge): nice 7, and with the kernel's autogroups
    (sched(7)) the group's nice 7 too, or the nice would not count against the other services' sessions."""
    import subprocess
    import sys

    code = ("import os; from edge.board import yield_cpu; n, g = yield_cpu(7); "
            "print(n, os.getpriority(os.PRIO_PROCESS, 0), g)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         start_new_session=True)
    assert out.returncode == 0, out.stderr
    nice, prio, group = out.stdout.split()
    assert int(nice) == 7 and int(prio) == 7
    try:
        autogroups = open("/proc/sys/kernel/sched_autogroup_enabled").read().strip() == "1"
    except OSError:
        autogroups = False
    assert group == ("7" if autogroups else "None")
    # not a session leader (run from a shell): the session's group, shared with the shell, is left alone
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.split()[2] == "None", (out.stdout, out.stderr)


class _Ticks:
    """A board that only counts its control-loop passes."""

    def __init__(self) -> None:
        self.ticks = 0

    def tick(self) -> None:
        self.ticks += 1


class _Session:
    def __init__(self) -> None:
        self.closed = False

    def close(self) -> None:
        self.closed = True


def test_the_board_keeps_ticking_while_its_session_reopens_and_retries(caplog):
    """Between two sessions (the edge applying a narrower ACL) the control loop never stops: the vehicle, the
    failsafe checks and the captures go on while the next session opens, and while a failed one is retried."""
    import logging
    import threading

    from edge.board import ControlLoop

    stop = threading.Event()
    loop = ControlLoop(50.0, stop, logging.getLogger("test-reopen"))
    board, attempts, opened = _Ticks(), [], _Session()

    def open_bus():
        attempts.append(board.ticks)
        time.sleep(0.3)  # a peer's open takes a while even when it succeeds
        if len(attempts) < 3:
            raise OSError("address already in use")
        return opened

    with caplog.at_level(logging.WARNING, logger="test-reopen"):
        assert loop.reopen(board, open_bus) is opened  # type: ignore[arg-type]
    assert len(attempts) == 3 and board.ticks > 40, (attempts, board.ticks)  # ~1.5 s at 50 Hz, never paused
    assert attempts[1] - attempts[0] >= 10 and attempts[2] - attempts[1] >= 10  # ticked through each try
    assert sum("did not reopen" in r.message for r in caplog.records) == 1  # said once, not per retry

    late = _Session()

    def slow_open():
        time.sleep(0.5)
        return late

    threading.Timer(0.1, stop.set).start()
    assert loop.reopen(board, slow_open) is None  # type: ignore[arg-type]  # stopped while opening
    assert _wait(lambda: late.closed, 3.0)  # the session that opened after the stop is closed
