"""The board's command, failsafe and staleness rules on the in-memory bus (protocol.membus): no processes,
a driver twin whose state the test sets, the wall clock the test moves. The same rules over real
processes and Zenoh: tests/edge/test_board.py."""

from __future__ import annotations

import dataclasses

import pytest

from edge import board as board_mod
from edge.board import Board, BoardOptions
from edge.failsafe import FailsafeOptions
from edge.vehicle.driver import DriverState
from edge.vehicle.mavlink import VehicleLinkError
from protocol import codec, keys
from protocol.links import COMMAND, TELEMETRY
from protocol.membus import MemBus, MemNetwork
from protocol.messages import (
    Box,
    CommandAck,
    Event,
    EventKind,
    Heartbeat,
    Land,
    Level,
    Mode,
    Resume,
    Takeoff,
    VehicleState,
)

FLEET = "rules"


class Wall:
    """The board's wall clock (``time.time`` of edge.board), moved by the test."""

    def __init__(self, t: float = 1.0e9) -> None:
        self.t = t

    def time(self) -> float:
        return self.t


class SimClock:
    speed = 1.0

    def now(self) -> float:
        return 0.0

    def sim_of(self, wall: float) -> float:
        return 0.0


class DriverTwin:
    """A vehicle driver whose state the test sets; ``fail`` maps an action to the error it raises."""

    def __init__(self) -> None:
        self.st = DriverState(t=0.0, pos=(10.0, 10.0, 5.0), vel=(0.0, 0.0, 0.0), att=(0.0, 0.0, 0.0),
                              rates=(0.0, 0.0, 0.0), mode=Mode.HOLD, armed=True, battery=0.9, wp_index=-1,
                              progress=0.0, captures=0)
        self.calls: list[str] = []
        self.fail: dict[str, Exception] = {}

    def set(self, **kw) -> None:
        self.st = dataclasses.replace(self.st, **kw)

    def _do(self, action: str) -> None:
        self.calls.append(action)
        if action in self.fail:
            raise self.fail[action]

    def state(self) -> DriverState:
        return self.st

    def step(self, t: float) -> list:
        return []

    def takeoff(self, altitude: float) -> None:
        self._do("takeoff")

    def hold(self) -> None:
        self._do("hold")

    def land(self) -> None:
        self._do("land")

    def return_to_launch(self) -> None:
        self._do("rtl")

    def resume(self) -> None:
        self._do("resume")

    def set_reference_offset(self, offset) -> None:
        pass


@pytest.fixture
def rig(monkeypatch):
    """(board, driver, wall clock, ground-station bus, events heard by the ground station)."""
    wall = Wall()
    monkeypatch.setattr(board_mod, "time", wall)
    net = MemNetwork()
    edge, gcs = MemBus(net, FLEET, "uav1"), MemBus(net, FLEET, "gcs")
    events: list[Event] = []
    gcs.subscribe(keys.all_events(FLEET), lambda m, s: events.append(m), expect=Event)
    driver = DriverTwin()
    opts = BoardOptions(uav=1, failsafe=FailsafeOptions(timeout_s=5.0, action="hold", escalate_after_s=30.0,
                                                         retry_s=1.0),
                        geofence=Box(lo=(0.0, 0.0, 0.0), hi=(100.0, 100.0, 40.0)))
    board = Board(edge, driver, SimClock(), opts)
    yield board, driver, wall, gcs, events
    edge.close()
    gcs.close()


def kinds(events: list[Event]) -> list[str]:
    return [e.kind for e in events]


# ----------------------------------------------------------------------------- commands
def test_a_valid_command_reaches_the_vehicle_an_invalid_one_is_refused_with_a_reason(rig):
    board, driver, wall, gcs, events = rig
    ok = gcs.request(keys.cmd(FLEET, 1), Takeoff(uav=1, cmd_id=1, altitude=5.0), expect=CommandAck)
    assert ok.ok and ok.message.accepted and driver.calls == ["takeoff"]
    high = gcs.request(keys.cmd(FLEET, 1), Takeoff(uav=1, cmd_id=2, altitude=80.0), expect=CommandAck)
    assert high.ok and not high.message.accepted and high.message.reason  # above the 40 m geofence
    other = gcs.request(keys.cmd(FLEET, 1), Land(uav=2, cmd_id=3), expect=CommandAck)
    assert other.ok and not other.message.accepted  # addressed to another UAV
    assert driver.calls == ["takeoff"]
    assert kinds(events) == [EventKind.COMMAND_REJECTED] * 2


def test_garbage_on_the_command_key_is_an_error_reply_and_counted(rig):
    board, driver, wall, gcs, events = rig
    got = gcs.session.net.query(gcs.session, keys.cmd(FLEET, 1), b"\x93garbage")
    assert len(got) == 1 and got[0].err is not None and got[0].ok is None
    assert any(k.startswith(keys.cmd(FLEET, 1)) for k in board.bus.counters.snapshot()["rejected"])
    assert driver.calls == []


# ----------------------------------------------------------------------------- failsafe
def heartbeat(gcs: MemBus, wall: Wall) -> None:
    gcs.publisher(keys.heartbeat(FLEET), COMMAND).put(Heartbeat(seq=int(wall.t), stamp=wall.t))


def test_lost_heartbeat_holds_and_a_resume_needs_a_fresh_heartbeat(rig):
    board, driver, wall, gcs, events = rig
    heartbeat(gcs, wall)
    board.tick()
    assert events == []
    wall.t += 5.5
    board.tick()
    assert driver.calls == ["hold"] and kinds(events) == [EventKind.FAILSAFE]
    assert events[0].data["ok"] is True and events[0].data["action"] == "hold"
    stale = gcs.request(keys.cmd(FLEET, 1), Resume(uav=1, cmd_id=1), expect=CommandAck)
    assert not stale.message.accepted and "heartbeat" in stale.message.reason
    wall.t += 0.5
    heartbeat(gcs, wall)
    fresh = gcs.request(keys.cmd(FLEET, 1), Resume(uav=1, cmd_id=2), expect=CommandAck)
    assert fresh.message.accepted and driver.calls[-1] == "resume"
    assert EventKind.FAILSAFE_CLEARED in kinds(events)


def test_a_failed_land_is_loud_retried_at_a_bounded_rate_and_reported_when_done(rig):
    """A LAND on a lost autopilot link: not reported as done; retried once a second; counted."""
    board, driver, wall, gcs, events = rig
    driver.fail["land"] = VehicleLinkError("no HEARTBEAT from the autopilot for 3.0 s")
    driver.set(battery=0.05)  # critical: land
    board.tick()
    assert driver.calls == ["land"]
    (ev,) = events
    assert ev.kind == EventKind.BATTERY_FAILSAFE and ev.level == Level.ERROR and ev.data["ok"] is False
    assert ev.data["failed"] == "land" and "no HEARTBEAT" in ev.data["error"] and "land failed" in ev.text
    for _ in range(5):  # same second: no retry storm
        board.tick()
    assert driver.calls == ["land"]
    wall.t += 1.0
    board.tick()
    assert driver.calls == ["land", "land"]
    assert events[-1].kind == EventKind.FAILSAFE_RETRY and events[-1].data["ok"] is False
    assert events[-1].data["attempts"] == 2
    del driver.fail["land"]
    wall.t += 1.0
    board.tick()
    assert driver.calls == ["land"] * 3
    assert events[-1].kind == EventKind.FAILSAFE_RETRY and events[-1].data["ok"] is True
    assert events[-1].data["attempts"] == 3
    wall.t += 5.0
    board.tick()
    assert driver.calls == ["land"] * 3  # done: nothing more


def test_a_failed_rtl_becomes_a_land_and_both_failing_keep_being_retried_and_said(rig):
    board, driver, wall, gcs, events = rig
    driver.fail["rtl"] = VehicleLinkError("COMMAND_ACK: MAV_RESULT_DENIED")
    driver.fail["land"] = VehicleLinkError("no COMMAND_ACK")
    driver.set(battery=0.15)  # low: return to launch
    board.tick()
    assert driver.calls == ["rtl"] and events[-1].data["next_action"] == "land"
    assert "rtl failed" in events[-1].text and "trying land instead" in events[-1].text
    for _ in range(4):
        wall.t += 1.0
        board.tick()
    assert driver.calls == ["rtl", "land", "land", "land", "land"]
    retries = [e for e in events if e.kind == EventKind.FAILSAFE_RETRY]
    assert [e.data["attempts"] for e in retries] == [2, 3, 4, 5] and all(not e.data["ok"] for e in retries)
    assert all(e.level == Level.ERROR for e in retries)
    driver.set(mode=Mode.LANDED, armed=False)  # down after all (the autopilot's own failsafe)
    wall.t += 1.0
    board.tick()
    assert len(driver.calls) == 5  # no retry on the ground


def test_a_failed_hold_is_retried_and_the_escalation_still_comes(rig):
    board, driver, wall, gcs, events = rig
    heartbeat(gcs, wall)
    board.tick()
    driver.fail["hold"] = VehicleLinkError("link lost")
    wall.t += 5.5
    board.tick()
    assert events[-1].kind == EventKind.FAILSAFE and events[-1].data["ok"] is False
    wall.t += 1.0
    board.tick()
    assert driver.calls == ["hold", "hold"]
    wall.t += 30.0
    board.tick()
    assert driver.calls[-1] == "rtl" and events[-1].kind == EventKind.FAILSAFE_ESCALATED
    assert events[-1].data["ok"] is True


# ----------------------------------------------------------------------------- staleness
def test_a_neighbour_state_going_stale_and_fresh_and_its_liveliness(rig):
    board, driver, wall, gcs, events = rig
    uav2 = MemBus(gcs.net, FLEET, "uav2")
    tok = uav2.token(keys.alive(FLEET, 2))
    pub = uav2.publisher(keys.state(FLEET, 2), TELEMETRY)

    def state(seq: int) -> VehicleState:
        return VehicleState(uav=2, seq=seq, t=0.0, stamp=wall.t, pos=(14.0, 10.0, 5.0), vel=(0.0, 0.0, 0.0),
                            att=(0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0), mode=Mode.HOLD)

    pub.put(state(0))
    assert board.tick().neighbours == 1
    wall.t += 1.5  # past the 1 s stale limit
    assert board.tick().neighbours == 0
    assert kinds(events)[-1] == EventKind.NEIGHBOUR_STALE and events[-1].data["neighbour"] == 2
    board.tick()
    assert kinds(events).count(EventKind.NEIGHBOUR_STALE) == 1  # once
    pub.put(state(1))
    assert board.tick().neighbours == 1 and kinds(events)[-1] == EventKind.NEIGHBOUR_FRESH
    tok.undeclare()
    assert kinds(events)[-1] == EventKind.NEIGHBOUR_LOST and board.tick().neighbours == 0
    # a state on UAV 2's key that says it is UAV 3: refused, counted, not a neighbour
    pub.put_bytes(codec.encode(state(2).model_copy(update={"uav": 3})))
    assert board.tick().neighbours == 0 and kinds(events)[-1] == EventKind.TRUST_REFUSED
    uav2.close()
