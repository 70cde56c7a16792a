"""protocol.membus: the Bus interface delivered in memory, with the real codec, counters and key matching;
and the event kinds of the wire contract (an unknown kind is a counted rejection)."""

from __future__ import annotations

import pytest

from protocol import codec, keys
from protocol.bus import Rejected
from protocol.links import COMMAND, TELEMETRY
from protocol.membus import MemBus, MemNetwork, intersects
from protocol.messages import Event, EventKind, Heartbeat


@pytest.fixture
def pair():
    net = MemNetwork()
    with MemBus(net, "f", "a") as a, MemBus(net, "f", "b") as b:
        yield a, b


def test_put_and_subscribe_decode_and_count_what_does_not_decode(pair):
    a, b = pair
    got = []
    b.subscribe(keys.heartbeat("f"), lambda m, s: got.append((m.seq, s.key_expr)), expect=Heartbeat, link=COMMAND)
    pub = a.publisher(keys.heartbeat("f"), COMMAND)
    assert pub.matching() is True
    pub.put(Heartbeat(seq=1, stamp=1.0))
    pub.put_bytes(b"not msgpack")
    pub.put(Event(source="gcs", stamp=1.0, kind=EventKind.PLAN_REFUSED))  # the wrong type
    a.publisher(keys.state("f", 1), TELEMETRY).put(Heartbeat(seq=2, stamp=1.0))  # another key: not heard
    assert got == [(1, keys.heartbeat("f"))]
    rejected = b.counters.snapshot()["rejected"]
    assert sum(rejected.values()) == 2 and all(k.startswith(keys.heartbeat("f")) for k in rejected)


def test_request_serve_reject_and_nobody_listening(pair):
    a, b = pair

    def handler(m):
        if m.seq == 0:
            raise Rejected("zero", "bad-seq")
        if m.seq == 1:
            raise RuntimeError("bug")
        return m

    b.serve("skynet/f/rcu/x/q", handler, expect=Heartbeat)
    ok = a.request("skynet/f/rcu/x/q", Heartbeat(seq=5, stamp=1.0), expect=Heartbeat)
    assert ok.ok and ok.message.seq == 5
    assert a.request("skynet/f/rcu/x/q", Heartbeat(seq=0, stamp=1.0)).error == "zero"
    assert "RuntimeError: bug" in a.request("skynet/f/rcu/x/q", Heartbeat(seq=1, stamp=1.0)).error
    assert "nobody listening" in a.request("skynet/f/rcu/y/q", Heartbeat(seq=5, stamp=1.0)).error
    b.serve("skynet/f/rcu/*/q", lambda m: m, expect=Heartbeat)  # a second answerer: request_all sees both
    assert len(a.request_all("skynet/f/rcu/x/q", Heartbeat(seq=5, stamp=1.0), expect=Heartbeat)) == 2
    assert len([r for r in [a.request("skynet/f/rcu/x/q", Heartbeat(seq=5, stamp=1.0))]]) == 1  # consolidated


def test_liveliness_tokens_watchers_history_and_a_dropped_session():
    net = MemNetwork()
    a, b = MemBus(net, "f", "a"), MemBus(net, "f", "b")
    tok = b.token(keys.alive("f", 2))
    seen = []
    a.watch_alive(keys.alive("f", "*"), lambda k, up: seen.append((k, up)))
    assert seen == [(keys.alive("f", 2), True)]  # current ones first
    c = MemBus(net, "f", "c")
    c.token(keys.alive("f", 3))
    assert a.alive(keys.fleet_all("f")) == [keys.alive("f", 2), keys.alive("f", 3)]
    tok.undeclare()
    c.close()  # its token leaves with it, as a lost session's does
    assert seen[1:] == [(keys.alive("f", 3), True), (keys.alive("f", 2), False), (keys.alive("f", 3), False)]
    got = []
    b.subscribe(keys.heartbeat("f"), lambda m, s: got.append(m), expect=Heartbeat)
    c.publisher(keys.heartbeat("f"), COMMAND).put(Heartbeat(seq=1, stamp=1.0))  # a closed session sends nothing
    assert got == [] and "c" not in a.peers()
    a.close()
    b.close()


def test_key_matching_is_zenohs():
    assert intersects("skynet/f/uav/*/state", "skynet/f/uav/2/state")
    assert intersects("skynet/f/**", "skynet/f/uav/2/state")
    assert not intersects("skynet/f/uav/*/state", "skynet/f/uav/2/event")
    assert not intersects("skynet/f/*", "skynet/f/uav/2")


def test_an_event_of_an_unknown_kind_is_a_counted_rejection(pair):
    a, b = pair
    got = []
    b.subscribe(keys.all_events("f"), lambda m, s: got.append(m.kind), expect=Event, link=COMMAND)
    pub = a.publisher(keys.event("f", 1), COMMAND)
    good = codec.encode(Event(source="uav/1", stamp=1.0, kind=EventKind.FAILSAFE))
    pub.put_bytes(good)
    pub.put_bytes(good.replace(b"failsafe", b"failsafX"))  # same length, an unknown kind
    assert got == [EventKind.FAILSAFE] and isinstance(got[0], EventKind)
    assert b.counters.snapshot()["rejected"] == {f"{keys.event('f', 1)}|invalid": 1}
    with pytest.raises(ValueError):
        Event(source="uav/1", stamp=1.0, kind="made-up")
