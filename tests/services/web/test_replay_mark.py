"""The page's "replay" label (services.web.service.replayed): the replay's mark counts only on a replay fleet's
keys (``F-replay``, the only keys the replay identity may write); a node that attaches it to the live fleet's
samples does not make them look replayed, and the forged mark is counted. On the in-memory bus
(protocol.membus): the subscriptions, decoding and counters are the page's own."""

from __future__ import annotations

from protocol import codec, keys
from protocol.links import COMMAND, TELEMETRY
from protocol.membus import MemBus, MemNetwork
from protocol.messages import Event, EventKind, Mode, VehicleState
from protocol.scenario import load_scenario
from services.recording.replay import REPLAY_MARK
from services.web.service import MISPLACED_MARK, attach
from services.web.view import FleetView


def state(uav: int) -> VehicleState:
    return VehicleState(uav=uav, seq=1, t=1.0, stamp=1.0e9, pos=(1.0, 2.0, 3.0), vel=(0, 0, 0), att=(0, 0, 0),
                        rates=(0, 0, 0), mode=Mode.MISSION)


def page(net: MemNetwork, fleet: str) -> tuple[MemBus, FleetView]:
    bus = MemBus(net, fleet, "web")
    view = FleetView(load_scenario(), fleet=fleet)
    attach(bus, view)
    return bus, view


def test_a_forged_replay_mark_on_the_live_fleet_is_ignored_and_counted():
    net = MemNetwork()
    web, view = page(net, "live")
    rogue = MemBus(net, "live", "uav2")  # a node with a valid identity, writing its own keys
    rogue.publisher(keys.state("live", 2), TELEMETRY).put_bytes(codec.encode(state(2)), attachment=REPLAY_MARK)
    ev = Event(source="uav/2", stamp=1.0e9, kind=EventKind.PILOT_MODE, text="x")
    rogue.publisher(keys.event("live", 2), COMMAND).put_bytes(codec.encode(ev), attachment=REPLAY_MARK)
    snap = view.snapshot()
    assert snap["source"] == "live" and snap["uavs"]["2"]["mode"] == "mission"  # shown, as live data
    rejected = web.counters.snapshot()["rejected"]
    assert rejected == {f"{keys.state('live', 2)}|{MISPLACED_MARK}": 1, f"{keys.event('live', 2)}|{MISPLACED_MARK}": 1}


def test_the_mark_on_a_replay_fleet_is_a_replay_and_unmarked_live_data_is_live():
    net = MemNetwork()
    fleet = keys.replay_fleet("live")
    web, view = page(net, fleet)
    replay = MemBus(net, fleet, "replay")
    replay.publisher(keys.state(fleet, 1), TELEMETRY).put_bytes(codec.encode(state(1)), attachment=REPLAY_MARK)
    assert view.snapshot()["source"] == "replay" and web.counters.snapshot()["rejected"] == {}
    live_web, live_view = page(net, "live")
    MemBus(net, "live", "uav1").publisher(keys.state("live", 1), TELEMETRY).put(state(1))
    assert live_view.snapshot()["source"] == "live" and live_web.counters.snapshot()["rejected"] == {}
