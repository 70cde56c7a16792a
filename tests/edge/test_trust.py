"""Issue 11's attacks against real processes over real mutual TLS: each now fails for the attacker.

A key set from ``skynet keys init``; the gateway and two edges run as processes with ``--keys``
on ``tls/`` endpoints (ACL by certificate common name on the gateway and on each edge). The test
process opens its sessions as the ground station (gcs certificate and signing key) and as the
attackers: anonymous, a certificate of another CA, and uav2's own certificate and keys.
"""

from __future__ import annotations

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
from services.process import free_port_pair
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
    gw_port, edge_port = free_port_pair()
    gw = [f"tls/127.0.0.1:{gw_port}"]
    edge1 = f"tls/127.0.0.1:{edge_port}"
    g = group.start("gateway", ["gateway", "--fleet", FLEET, "--keys", str(keyset), "--listen", gw[0],
                                "--period", "0.3"])
    assert g.wait_for("router up", 20), "\n".join(g.lines)
    common = ["--fleet", FLEET, "--keys", str(keyset), "--camera", "none", "--speed", "4",
              "--failsafe-timeout", "2", "--geofence", "0,0,0,100,100,40", "--connect", gw[0]]
    edges = {1: group.start("uav1", ["edge", "--uav", "1", "--home", "10,10,0", "--listen", edge1, *common])}
    assert edges[1].wait_for("board up", 30), "\n".join(edges[1].lines)
    edges[2] = group.start("uav2", ["edge", "--uav", "2", "--home", "14,10,0", "--connect", edge1,
                                    "--listen", "tls/127.0.0.1:0", *common])
    assert edges[2].wait_for("board up", 30), "\n".join(edges[2].lines)
    return {"gateway": gw, "edge1": [edge1], "edges": edges}


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
