"""Attacks against real processes over real mutual TLS: each now fails for the attacker.

A key set from ``skynet keys init``; the gateway and two edges run as processes with ``--keys``
on ``tls/`` endpoints (ACL by certificate common name on the gateway and on each edge). The test
process opens its sessions as the ground station (gcs certificate and signing key) and as the
attackers: anonymous, a certificate of another CA, and uav2's own certificate and keys.
"""

from __future__ import annotations

import socket
import time

import pytest
import zenoh

from edge.trust import Gate
from protocol import codec, keys
from protocol.bus import Bus, BusConfig
from protocol.keyset import KeySet
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import CommandAck, Event, Heartbeat, Land, Mode, Takeoff, VehicleState
from protocol.signing import Signer
from services.keys import init
from services.orchestration.process import free_port
from tests.conftest import wait_until

FLEET = "test"


def tls(ks: KeySet, mode: str, connect: list[str], **kw) -> BusConfig:
    return BusConfig(mode=mode, connect=connect, tls_ca=str(ks.ca), tls_cert=str(ks.tls_cert),
                     tls_key=str(ks.tls_key), connect_timeout_s=3.0, **kw)


@pytest.fixture(scope="module")
def keyset(tmp_path_factory):
    return init(tmp_path_factory.mktemp("keys"), uavs=3)


@pytest.fixture
def secure_fleet(group, keyset):
    gw_port, edge_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    gw = [f"tls/127.0.0.1:{gw_port}"]
    edge1 = f"tls/127.0.0.1:{edge_port}"
    g = group.start("gateway", ["gateway", "--fleet", FLEET, "--keys", str(keyset), "--listen", gw[0],
                                "--period-s", "0.3"])
    assert g.wait_ready(20), "\n".join(g.lines)
    common = ["--fleet", FLEET, "--keys", str(keyset), "--camera", "none", "--speed", "4",
              "--failsafe-timeout-s", "2", "--geofence", "0,0,0,100,100,40", "--connect", gw[0]]
    edges = {1: group.start("uav1", ["edge", "--uav", "1", "--home", "10,10,0", "--listen", edge1, *common])}
    assert edges[1].wait_ready(30), "\n".join(edges[1].lines)
    edges[2] = group.start("uav2", ["edge", "--uav", "2", "--home", "14,10,0", "--connect", edge1,
                                    "--listen", "tls/127.0.0.1:0", *common])
    assert edges[2].wait_ready(30), "\n".join(edges[2].lines)
    return {"gateway": gw, "edge1": [edge1], "edges": edges}


def attacker(config: BusConfig, name: str):
    """A session that may not open at all (refused at the TLS handshake): None then."""
    try:
        return Bus(config, FLEET, name)
    except zenoh.ZError:
        return None


def test_every_attack_of_the_issue_fails(secure_fleet, keyset, tmp_path, group):
    gcs_ks, uav2_ks = KeySet(keyset, "gcs"), KeySet(keyset, "uav2")
    gw, edge1 = secure_fleet["gateway"], secure_fleet["edge1"]
    states, events = {}, []
    with Bus(tls(gcs_ks, "client", gw), FLEET, "gcs") as gcs:
        gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: states.__setitem__(m.uav, m), expect=VehicleState,
                      link=TELEMETRY)
        gcs.subscribe(keys.all_events(FLEET), lambda m, s: events.append(m), expect=Event)
        assert wait_until(lambda: len(states) == 2 and all(s.neighbours == 1 for s in states.values()), 60), (
            states, [e.lines[-20:] for e in secure_fleet["edges"].values()])
        signer = gcs_ks.signer()
        cmd1 = keys.cmd(FLEET, 1)

        # anonymous (no certificate) and wrong-CA nodes cannot connect: not to the gateway, not to an edge
        other = KeySet(init(tmp_path / "other", uavs=2), "gcs")
        for where in (gw, edge1):
            assert attacker(BusConfig(mode="client", connect=where, tls_ca=str(gcs_ks.ca), connect_timeout_s=2), "anon") is None
            assert attacker(tls(other, "client", where), "wrong-ca") is None

        # unsigned, wrongly signed, tampered: refused with the reason in the acknowledgement
        plain = gcs.request(cmd1, Takeoff(uav=1, cmd_id=1, altitude=5), expect=CommandAck)
        assert plain.ok and not plain.message.accepted and plain.message.reason.startswith("trust: unsigned"), plain
        forged = Signer("gcs", uav2_ks.signer()._key).sign(Takeoff(uav=1, cmd_id=2, altitude=5), cmd1)
        r = gcs.request(cmd1, forged, expect=CommandAck)
        assert r.ok and not r.message.accepted and "unknown-signer" in r.message.reason, r
        older = signer.sign(Takeoff(uav=1, cmd_id=6, altitude=5), cmd1)  # signed first, sent after ``good``
        good = signer.sign(Takeoff(uav=1, cmd_id=3, altitude=5), cmd1)
        r = gcs.request(cmd1, good.model_copy(update={"body": signer.sign(Land(uav=1, cmd_id=3), cmd1).body}),
                        expect=CommandAck)
        assert r.ok and not r.message.accepted and "bad-signature" in r.message.reason, r
        stale = Signer("gcs", signer._key, clock=lambda: time.time() - 60).sign(Takeoff(uav=1, cmd_id=4), cmd1)
        r = gcs.request(cmd1, stale, expect=CommandAck)
        assert r.ok and not r.message.accepted and "stale" in r.message.reason, r
        # a command signed for UAV 3 and relayed to UAV 1 is refused
        r = gcs.request(cmd1, signer.sign(Takeoff(uav=1, cmd_id=5), keys.cmd(FLEET, 3)), expect=CommandAck)
        assert r.ok and not r.message.accepted and "wrong-addressee" in r.message.reason, r
        assert states[1].mode == Mode.IDLE

        # the ground station's signed command is obeyed; captured and re-sent (or re-ordered), refused
        r = gcs.request(cmd1, good, expect=CommandAck)
        assert r.ok and r.message.accepted, r
        for replay in (good, older):
            r = gcs.request(cmd1, replay, expect=CommandAck)
            assert r.ok and not r.message.accepted and "replayed" in r.message.reason, r
        assert wait_until(lambda: states[1].mode == Mode.HOLD and states[1].pos[2] > 4.0, 60), states[1]

        # heartbeats keep UAV 1 out of failsafe; then the ground station goes silent while uav2's identity
        # forges heartbeats (unsigned, and signed with its own key) through the gateway and straight to edge 1
        hb_pub = gcs.publisher(keys.heartbeat(FLEET), COMMAND)
        forgers = [Bus(tls(uav2_ks, "client", gw), FLEET, "forger-gw"),
                   Bus(tls(uav2_ks, "peer", edge1, listen=[]), FLEET, "forger-mesh")]
        try:
            pubs = [f.publisher(keys.heartbeat(FLEET), COMMAND) for f in forgers]
            own = uav2_ks.signer()
            for _ in range(10):
                hb_pub.put(signer.sign(Heartbeat(seq=1, stamp=time.time()), keys.heartbeat(FLEET)))
                time.sleep(0.2)
            assert not any(e.kind == "failsafe" for e in events), events
            silent_since = time.time()
            seq = 0
            while time.time() - silent_since < 6.0 and not any(e.kind == "failsafe" for e in events):
                seq += 1
                for p in pubs:
                    p.put(Heartbeat(seq=seq, stamp=time.time()))
                    p.put(own.sign(Heartbeat(seq=seq, stamp=time.time()), keys.heartbeat(FLEET)))
                time.sleep(0.1)
            assert wait_until(lambda: any(e.kind == "failsafe" and e.source == "uav/1" for e in events), 10), events
            fs = next(e for e in events if e.kind == "failsafe" and e.source == "uav/1")
            assert fs.data["silent_s"] < 2.0 + 1.0  # on time (2 s timeout, plus ticks under load)

            # uav2's identity cannot command anyone: not through the gateway, not straight over SkyNet
            for f in forgers:
                for uav in (1, 3):
                    key = keys.cmd(FLEET, uav)
                    r = f.request(key, signer.sign(Land(uav=uav, cmd_id=9), key), expect=CommandAck, timeout=1.0)
                    assert not r.ok, r  # the ACL drops the query: no UAV hears it
            assert states[1].mode == Mode.HOLD

            # nor impersonate: a state saying uav=1 on uav2's key (its own, allowed by the ACL) is refused,
            # at the edges and at the ground station
            from protocol.scenario import load_scenario
            from services.gcs.mission import MissionOptions, MissionRunner
            runner = MissionRunner(gcs, load_scenario(), MissionOptions(uavs=(1, 2)))
            for f in forgers:
                pub = f.publisher(keys.state(FLEET, 2), TELEMETRY)
                fake = states[1].model_copy(update={"pos": (10.0, 10.0, 1.0), "seq": 10**9})
                for _ in range(20):
                    pub.put(fake)
                    time.sleep(0.05)
            assert wait_until(lambda: any(e.kind == "trust-refused" and e.data.get("what") == "body.mismatch"
                                          and e.source == "uav/1" for e in events), 10), events
            assert runner.latest[1].seq != 10**9 and runner.latest[1].pos[2] > 4.0, runner.latest[1]
            rejected = gcs.counters.snapshot()["rejected"]
            assert rejected.get(f"{keys.state(FLEET, 2)}|body-mismatch", 0) > 0, rejected
            # nor put on another UAV's key: the ACL (gateway and edge) drops it
            before = states[1].seq
            for f in forgers:
                f.publisher(keys.state(FLEET, 1), TELEMETRY).put(fake)
            time.sleep(0.5)
            assert states[1].seq != 10**9 and states[1].seq >= before
        finally:
            for f in forgers:
                f.close()

    # the replay window survives an edge restart: the captured command is still refused
    edge = secure_fleet["edges"][1]
    edge.proc.kill()
    edge.proc.wait()
    # (a long stale window, so that only the persisted sequence can refuse it)
    restarted = group.start("uav1-again", [*edge.args, "--trust-window-s", "600"])
    assert restarted.wait_ready(30), "\n".join(restarted.lines)
    with Bus(tls(gcs_ks, "client", gw), FLEET, "gcs2") as gcs:
        assert wait_until(lambda: (gcs.request(cmd1, good, expect=CommandAck, timeout=1.0)).ok, 30)
        r = gcs.request(cmd1, good, expect=CommandAck)
        assert r.ok and not r.message.accepted and "replayed" in r.message.reason, r


def test_revoked_key_is_refused_by_a_running_edge_after_restart(tmp_path):
    """Rotation/revocation without code: a key id in revoked.txt is refused (the verifier reads it at start)."""
    from services.keys import revoke

    root = init(tmp_path / "k", uavs=1)
    ks = KeySet(root, "uav1")
    gcs = KeySet(root, "gcs").signer()
    revoke(root, str(root / "gcs" / "sign.pub"))
    gate = Gate(FLEET, 1, ks.verifier(persist=False))
    from protocol.signing import TrustError
    with pytest.raises(TrustError, match="revoked"):
        gate.command(gcs.sign(Land(uav=1, cmd_id=1), keys.cmd(FLEET, 1)))
    assert gate.counters() == {"command.revoked": 1}


def test_secure_fleet_smoke(secure_fleet, keyset):
    ks = KeySet(keyset, "gcs")
    states, events = {}, []
    with Bus(tls(ks, "client", secure_fleet["gateway"]), FLEET, "gcs") as gcs:
        gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: states.__setitem__(m.uav, m), expect=VehicleState,
                      link=TELEMETRY)
        gcs.subscribe(keys.all_events(FLEET), lambda m, s: events.append(m), expect=Event)
        assert wait_until(lambda: len(states) == 2 and all(s.neighbours == 1 for s in states.values()), 30), (
            states, [e.lines[-20:] for e in secure_fleet["edges"].values()])
        signer = ks.signer()
        key = keys.cmd(FLEET, 1)
        plain = gcs.request(key, Takeoff(uav=1, cmd_id=1, altitude=5), expect=CommandAck)
        assert plain.ok and not plain.message.accepted and "unsigned" in plain.message.reason, plain
        ok = gcs.request(key, signer.sign(Takeoff(uav=1, cmd_id=2, altitude=5), key), expect=CommandAck)
        assert ok.ok and ok.message.accepted, ok


def test_a_read_only_key_set_keeps_the_replay_window_elsewhere(tmp_path):
    """docker compose mounts the key set read-only: ``--replay-state FILE`` holds the window instead."""
    import argparse
    import os
    import stat

    from edge.trust import secure_setup

    root = init(tmp_path / "k", uavs=1)
    state = tmp_path / "state" / "replay.json"
    state.parent.mkdir()
    gcs = KeySet(root, "gcs").signer()
    modes = {p: p.stat().st_mode for p in [root, *root.rglob("*")]}
    for p in modes:  # read-only, as a :ro mount is
        os.chmod(p, modes[p] & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))
    try:
        args = argparse.Namespace(uav=1, fleet=FLEET, keys=str(root), insecure=False, trust_window=10.0,
                                  mesh_uavs=None, listen=[], connect=[], replay_state=str(state))
        gate, _ = secure_setup(args)
        env = gcs.sign(Land(uav=1, cmd_id=1), keys.cmd(FLEET, 1))
        assert isinstance(gate.command(env), Land)
        assert not (root / "uav1" / "replay.json").exists() and state.exists()
        # a restarted edge reads it back: the same envelope is a replay
        gate2, _ = secure_setup(args)
        from protocol.signing import TrustError
        with pytest.raises(TrustError, match="replayed"):
            gate2.command(env)
    finally:
        for p, m in modes.items():
            os.chmod(p, m)


@pytest.mark.parametrize("body", ["%%% not base64", "", "AAAA", None])
def test_the_cmd_id_of_a_refused_envelope_is_read_without_trusting_it(body):
    """A forged envelope's body may be anything: command_id gives 0 for garbage, never raises."""
    import base64

    from edge.trust import command_id
    from protocol.messages import Heartbeat, Land, Signed

    text = base64.b64encode(codec.encode(Heartbeat(seq=1, stamp=1.0))).decode() if body is None else body
    env = Signed(signer="x", kid="0123456789abcdef", seq=1, stamp=1.0, to="skynet/demo/uav/1/cmd",
                 type="cmd.land", body=text, sig="AAAA")
    assert command_id(env) == 0  # garbage, or a body that is not a command
    good = Signed(signer="x", kid="0123456789abcdef", seq=1, stamp=1.0, to="skynet/demo/uav/1/cmd", type="cmd.land",
                  body=base64.b64encode(codec.encode(Land(uav=1, cmd_id=41))).decode(), sig="AAAA")
    assert command_id(good) == 41


def test_a_key_revoked_beside_a_running_gate_is_refused_at_once(tmp_path):
    """``skynet keys revoke`` while the board runs: the next command and heartbeat signed with that key are
    refused, without a restart (the watch reads revoked.txt again when it changes)."""
    from protocol.keyset import RevocationWatch
    from protocol.signing import TrustError
    from services.keys import revoke

    root = init(tmp_path / "k", uavs=1)
    ks = KeySet(root, "uav1")
    gcs = KeySet(root, "gcs").signer()
    gate = Gate(FLEET, 1, ks.verifier(persist=False), revocations=RevocationWatch(ks, min_interval_s=0))
    assert gate.command(gcs.sign(Land(uav=1, cmd_id=1), keys.cmd(FLEET, 1))) == Land(uav=1, cmd_id=1)
    assert gate.heartbeat(gcs.sign(Heartbeat(seq=1, stamp=time.time()), keys.heartbeat(FLEET))) is None
    revoke(root, str(root / "gcs" / "sign.pub"))
    with pytest.raises(TrustError, match="revoked"):
        gate.command(gcs.sign(Land(uav=1, cmd_id=2), keys.cmd(FLEET, 1)))
    refused = gate.heartbeat(gcs.sign(Heartbeat(seq=2, stamp=time.time()), keys.heartbeat(FLEET)))
    assert refused is not None and "revoked" in str(refused)
    assert gate.counters() == {"command.revoked": 1, "heartbeat.revoked": 1}


def test_a_running_edge_refuses_a_key_revoked_beside_it_without_a_restart(tmp_path, group):
    """A secure edge process, then ``skynet keys revoke DIR KEY`` of the ground station's signing key: its next
    command is refused as revoked within seconds; the edge was not restarted."""
    from services.keys import revoke

    root = init(tmp_path / "k", uavs=1)
    port = free_port(socket.SOCK_STREAM)
    gw = [f"tls/127.0.0.1:{port}"]
    g = group.start("gateway", ["gateway", "--fleet", FLEET, "--keys", str(root), "--listen", gw[0]])
    assert g.wait_ready(20), "\n".join(g.lines)
    edge = group.start("uav1", ["edge", "--uav", "1", "--home", "10,10,0", "--fleet", FLEET, "--keys", str(root),
                                "--camera", "none", "--speed", "4", "--geofence", "0,0,0,100,100,40",
                                "--connect", gw[0]])
    assert edge.wait_ready(30), "\n".join(edge.lines)
    gcs_ks = KeySet(root, "gcs")
    signer, cmd1 = gcs_ks.signer(), keys.cmd(FLEET, 1)
    with Bus(tls(gcs_ks, "client", gw), FLEET, "gcs") as gcs:
        r = None

        def ack(cmd_id: int):
            nonlocal r
            r = gcs.request(cmd1, signer.sign(Takeoff(uav=1, cmd_id=cmd_id, altitude=5), cmd1), expect=CommandAck,
                            timeout=1.0)
            return r.ok

        assert wait_until(lambda: ack(1), 30), r
        assert r.message.accepted, r
        revoke(root, str(root / "gcs" / "sign.pub"))
        ids = iter(range(2, 100))
        assert wait_until(lambda: ack(next(ids)) and "revoked" in r.message.reason, 10), r
        assert not r.message.accepted
    assert edge.proc.poll() is None and any("revoked signing keys now" in ln for ln in edge.lines), edge.lines[-10:]
