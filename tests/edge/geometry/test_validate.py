"""The board's geofence only narrows: configured or signed, a later upload cannot widen it (edge.geometry.validate)."""

from __future__ import annotations

import pytest

from edge.geometry.validate import narrowed_fence, validate_command
from protocol.messages import Box, Trajectory, UploadTrajectory, Waypoint

BOX = Box(lo=(0, 0, 0), hi=(101, 141, 40))
WIDE = Box(lo=(-3000, -3000, 0), hi=(3000, 3000, 150))


def upload(pos, fence):
    traj = Trajectory(uav=1, waypoints=[Waypoint(t=0, pos=(10, 10, 5)), Waypoint(t=100, pos=pos)])
    return UploadTrajectory(uav=1, cmd_id=1, trajectory=traj, geofence=fence)


def test_a_wider_fence_never_replaces_the_boards():
    assert narrowed_fence(None, BOX) == BOX  # the first signed fence
    assert narrowed_fence(BOX, WIDE) == BOX  # a wider one: the board keeps its own
    inner = Box(lo=(10, 10, 0), hi=(50, 50, 30))
    assert narrowed_fence(BOX, inner) == inner
    assert narrowed_fence(BOX, Box(lo=(50, -10, 0), hi=(200, 60, 120))) == Box(lo=(50, 0, 0), hi=(101, 60, 40))
    with pytest.raises(ValueError, match="does not overlap"):
        narrowed_fence(BOX, Box(lo=(400, 0, 0), hi=(500, 100, 40)))


def test_an_upload_must_stay_inside_the_boards_fence_and_its_own():
    assert validate_command(upload((90, 130, 30), WIDE), 1, BOX, 12.0) == ""
    assert "outside the geofence" in validate_command(upload((520, 130, 120), WIDE), 1, BOX, 12.0)
    # a trajectory outside the fence it comes with is refused even by a board with a wider fence
    assert "outside the geofence" in validate_command(upload((90, 130, 30), Box(lo=(0, 0, 0), hi=(50, 50, 40))),
                                                      1, WIDE, 12.0)
    # no fence of its own (unconfigured, --insecure): the upload's
    assert "outside the geofence" in validate_command(upload((520, 130, 30), BOX), 1, None, 12.0)


def test_a_running_edge_keeps_its_first_signed_fence_over_mutual_tls(group, tmp_path):
    """A real edge without --geofence, in the secure mode: the first signed upload's fence is its ceiling."""
    import socket

    from protocol import keys
    from protocol.bus import Bus, BusConfig
    from protocol.keyset import KeySet
    from protocol.messages import CommandAck, Event
    from services.keys import init
    from services.orchestration.process import free_port
    from tests.conftest import wait_until

    fleet = "fence"
    root = init(tmp_path / "keys", uavs=1)
    gw = f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    g = group.start("gateway", ["gateway", "--fleet", fleet, "--keys", str(root), "--listen", gw, "--period-s", "0.3"])
    assert g.wait_ready(20), "\n".join(g.lines)
    e = group.start("uav1", ["edge", "--uav", "1", "--fleet", fleet, "--keys", str(root), "--camera", "none",
                             "--speed", "4", "--home", "10,10,0", "--connect", gw, "--listen", "tls/127.0.0.1:0"])
    assert e.wait_ready(30), "\n".join(e.lines)
    ks = KeySet(root, "gcs")
    cfg = BusConfig(mode="client", connect=[gw], tls_ca=str(ks.ca), tls_cert=str(ks.tls_cert), tls_key=str(ks.tls_key))
    signer, key = ks.signer(), keys.cmd(fleet, 1)
    events: list[Event] = []
    with Bus(cfg, fleet, "gcs") as gcs:
        gcs.subscribe(keys.all_events(fleet), lambda m, s: events.append(m), expect=Event)

        def send(cmd) -> CommandAck:
            r = gcs.request(key, signer.sign(cmd, key), expect=CommandAck, timeout=5.0)
            assert r.ok, r
            return r.message

        assert wait_until(lambda: keys.alive(fleet, 1) in gcs.alive(keys.fleet_all(fleet), timeout=1.0), 30)
        first = send(upload((90, 130, 30), BOX))
        assert first.accepted, first
        # the rogue plan's wide fence and a trajectory 420 m out: refused, the board's fence stands
        far = send(upload((520, 130, 120), WIDE).model_copy(update={"cmd_id": 2}))
        assert not far.accepted and "outside the geofence" in far.reason, far
        # a wide fence with a trajectory inside the first: flown, but the fence stays the first one
        inside = send(upload((90, 130, 30), WIDE).model_copy(update={"cmd_id": 3}))
        assert inside.accepted, inside
        again = send(upload((101, 141, 41), WIDE).model_copy(update={"cmd_id": 4}))
        assert not again.accepted and "outside the geofence" in again.reason, again
        # a narrower signed fence narrows it (and says so)
        inner = Box(lo=(0, 0, 0), hi=(95, 135, 35))
        assert send(upload((90, 130, 30), inner).model_copy(update={"cmd_id": 5})).accepted
        assert not send(upload((94, 130, 36), WIDE).model_copy(update={"cmd_id": 6})).accepted
        assert wait_until(lambda: any(ev.kind == "geofence-narrowed" for ev in events), 10), events
