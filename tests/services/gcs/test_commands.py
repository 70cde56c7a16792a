"""services.gcs.commands: tries, back-off and records, against a real queryable on a real Zenoh session.

One in-process peer session (no other process) serves a UAV's ``cmd`` key and sends the commands
to itself; the back-off pauses are collected instead of slept, so nothing here waits for them.
"""

from __future__ import annotations

import threading

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig, Rejected
from protocol.messages import CommandAck, Hold, Land
from services.gcs.commands import CommandIds, RetryPolicy, not_sent, send, start_margin
from services.recording.record import CommandRecord

FLEET = "cmdtest"


@pytest.fixture(scope="module")
def bus():
    with Bus(BusConfig(mode="peer"), FLEET, "gcs") as b:
        yield b


def test_an_answer_ends_the_tries_even_a_refusal(bus):
    calls = []

    def handle(m):
        calls.append(m.cmd_id)
        return CommandAck(uav=1, cmd_id=m.cmd_id, accepted=m.kind == "land", reason="" if m.kind == "land" else "no")

    bus.serve(keys.cmd(FLEET, 1), handle, expect=(Land, Hold))
    pauses: list[float] = []
    ok = send(bus, Land(uav=1, cmd_id=7), RetryPolicy(), sleep=pauses.append)
    assert (ok.ok, ok.accepted, ok.attempts, ok.cmd_id, ok.kind, len(ok.ack_s)) == (True, True, 1, 7, "land", 1)
    refused = send(bus, Hold(uav=1, cmd_id=8), RetryPolicy(), sleep=pauses.append)
    assert (refused.ok, refused.accepted, refused.reason, refused.attempts) == (True, False, "no", 1)
    assert calls == [7, 8] and pauses == []  # not retried


def test_no_answer_is_tried_again_with_back_off(bus):
    pauses: list[float] = []
    rec = send(bus, Land(uav=2, cmd_id=1), RetryPolicy(attempts=3, timeout_s=0.2), sleep=pauses.append)
    assert not rec.ok and not rec.accepted and rec.attempts == 3 and rec.ack_s == []
    assert "nobody listening" in rec.reason
    assert pauses == [0.25, 0.5, 1.0]


def test_an_error_reply_is_tried_again_until_acknowledged(bus):
    failures = iter(["busy", "busy"])

    def handle(m):
        reason = next(failures, None)
        if reason:
            raise Rejected(reason)
        return CommandAck(uav=3, cmd_id=m.cmd_id, accepted=True)

    bus.serve(keys.cmd(FLEET, 3), handle, expect=Land)
    pauses: list[float] = []
    rec = send(bus, Land(uav=3, cmd_id=4), RetryPolicy(attempts=4), sleep=pauses.append)
    assert rec.ok and rec.accepted and rec.attempts == 3 and len(rec.ack_s) == 1
    assert pauses == [0.25, 0.5]
    rec = send(bus, Land(uav=3, cmd_id=5), RetryPolicy(attempts=1), sleep=pauses.append)
    assert rec.ok and rec.attempts == 1  # the handler answers from now on


def test_not_sent_and_ids():
    rec = not_sent(Land(uav=4, cmd_id=9), "UAV 4 is lost")
    assert (rec.ok, rec.attempts, rec.reason, rec.cmd_id) == (False, 0, "not sent: UAV 4 is lost", 9)
    ids = CommandIds()
    got: list[int] = []
    threads = [threading.Thread(target=lambda: got.extend(ids.next() for _ in range(100))) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(got) == list(range(1, 401))


def test_start_margin_and_policy_bounds():
    def acked(*s):
        return CommandRecord(uav=1, kind="takeoff", cmd_id=1, ok=True, accepted=True, elapsed_s=max(s), ack_s=list(s))

    assert start_margin([], 2.0) == 2.0
    assert start_margin([acked(0.01), acked(0.8)], 2.0) == pytest.approx(2.0)
    assert start_margin([acked(0.2, 1.5)], 2.0) == pytest.approx(3.0)
    assert start_margin([acked(60.0)], 2.0) == 30.0
    for bad in ({"attempts": 0}, {"timeout_s": 0.0}, {"backoff_s": -1.0}):
        with pytest.raises(ValueError):
            RetryPolicy(**bad)
