"""Trust at the seams, with real processes and real certificates: a gateway with a plaintext listener, an
impaired network started by the launcher, a revoked or re-issued node, a node posing as the gateway.

Each key set is made in the test's own temporary folder (never the user's ``.keys/dev``).
"""

from __future__ import annotations

import itertools
import socket
import time

import pytest
import zenoh

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.heap import settled_resident_mb
from protocol.keyset import KeySet
from protocol.links import TELEMETRY
from protocol.messages import CommandAck, Hold, Mode, VehicleState
from services.keys import init
from services.orchestration.process import free_port
from tests.conftest import wait_until
from tests.readiness import ServiceGroup

FLEET = "seams"


def tls(ks: KeySet, mode: str, connect: list[str], **kw) -> BusConfig:
    return BusConfig(mode=mode, connect=connect, tls_ca=str(ks.tls_ca), tls_cert=str(ks.tls_cert),
                     tls_key=str(ks.tls_key), connect_timeout_s=3.0, **kw)


def opened(config: BusConfig, name: str) -> Bus | None:
    """A session, or None when it cannot open at all (refused at the TLS handshake, nobody answering)."""
    try:
        return Bus(config, FLEET, name)
    except zenoh.ZError:
        return None


def state(uav: int, seq: int = 0) -> VehicleState:
    return VehicleState(uav=uav, seq=seq, t=0.0, stamp=time.time(), pos=(1.0, 2.0, 3.0), vel=(0, 0, 0),
                        att=(0, 0, 0), rates=(0, 0, 0), mode=Mode.HOLD)


class Watch:
    """States received on one session, by UAV."""

    def __init__(self, bus: Bus):
        self.got: dict[int, int] = {}
        bus.subscribe(keys.state(FLEET, "*"), self._on, expect=VehicleState, link=TELEMETRY)

    def _on(self, msg: VehicleState, sample) -> None:
        self.got[msg.uav] = self.got.get(msg.uav, 0) + 1


def test_a_gateway_with_keys_applies_its_acl_to_a_plaintext_listener_too(tmp_path, group):
    ks_dir = init(tmp_path / "keys", uavs=2)
    tls_port, tcp_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    tls_ep, tcp_ep = f"tls/127.0.0.1:{tls_port}", f"tcp/127.0.0.1:{tcp_port}"
    gw = group.start("gateway", ["gateway", "--fleet", FLEET, "--keys", str(ks_dir), "--listen", tls_ep,
                                 "--listen", tcp_ep, "--state-ingress-hz", "0"])
    assert gw.wait_ready(20), "\n".join(gw.lines)
    assert any("without TLS" in ln and tcp_ep in ln for ln in gw.lines), gw.lines[-10:]
    gcs = Bus(tls(KeySet(ks_dir, "gcs"), "client", [tls_ep]), FLEET, "gcs")
    uav1 = Bus(tls(KeySet(ks_dir, "uav1"), "client", [tls_ep]), FLEET, "uav1")
    uav2 = Bus(tls(KeySet(ks_dir, "uav2"), "client", [tls_ep]), FLEET, "uav2")
    anon = Bus(BusConfig(mode="client", connect=[tcp_ep], connect_timeout_s=3.0), FLEET, "anon")
    try:
        seen, stolen = Watch(gcs), Watch(anon)
        asked: list[str] = []
        anon.serve(keys.cmd(FLEET, 1), lambda msg, q: asked.append("anon"))
        time.sleep(1.0)
        for i in range(30):
            uav1.publisher(keys.state(FLEET, 1), TELEMETRY).put(state(1, i))
            uav2.publisher(keys.state(FLEET, 1), TELEMETRY).put(state(1, 1000 + i))  # uav2 speaking for uav1
            anon.publisher(keys.state(FLEET, 2), TELEMETRY).put(state(2, i))  # the anonymous one for uav2
            time.sleep(0.03)
        assert wait_until(lambda: seen.got.get(1, 0) >= 20, 10), seen.got
        time.sleep(0.5)
        assert seen.got.get(1, 0) == 30, f"uav2's forged states for uav1 reached the ground station: {seen.got}"
        assert 2 not in seen.got, "the anonymous client's states reached the ground station"
        assert 1 not in stolen.got, f"the anonymous client read uav1's states: {stolen.got}"  # (its own: local)
        reply = gcs.request(keys.cmd(FLEET, 1), Hold(uav=1, cmd_id=1), timeout=1.0)
        assert not reply.ok and asked == [], (reply, asked)
    finally:
        for b in (anon, uav2, uav1, gcs):
            b.close()


def test_an_impaired_network_keeps_identities_and_the_acl(tmp_path):
    """``skynet up --impair uav2="delay 1ms"`` through the launcher, default secure mode: the links run through the
    netem proxies and still carry mutual TLS, so an anonymous client (plaintext, or TLS without a certificate) opens
    no session on the gateway, on an edge or on a proxy, while the ground station sees the fleet and commands it.
    Then ``skynet keys revoke DIR uav2`` beside it: the gateway cuts uav2 off while the others stay in view; and
    ``skynet keys revoke DIR gcs/sign.pub``: the running edges refuse the ground station's next signed command."""
    from services.keys import main as keys_main
    from services.orchestration.launcher import Network, parse
    from tests.services.orchestration.test_topology import Probe

    args = parse("up", ["--speed", "8", "--fleet", FLEET, "--camera", "none",
                                          "--keys", str(tmp_path / "keys"), "--impair", "uav2=delay 1ms"])
    net = Network(args, echo=None)
    assert net.trust.tls and net.plan.proxied
    net.start()
    probe = None
    try:
        probe = Probe(net.gcs_config(), FLEET)
        assert wait_until(lambda: all(probe.fresh(u) for u in (1, 2, 3)), 40), probe.last
        assert all(probe.answered(u) for u in (1, 2, 3))
        targets = [*net.gateway_endpoints, *(e for ends in net.edge_endpoints.values() for e in ends),
                   *(net._proxied_ends(link) for link in net.proxies)]
        targets = [e for t in targets for e in ([t] if isinstance(t, str) else t)]
        assert any(p["udp"].kind == "tcp" for p in net.proxies.values()), "the best-effort class is proxied as TLS"
        gcs_ks = KeySet(tmp_path / "keys", "gcs")
        for where in targets:
            plain = where.replace("tls/", "tcp/")
            for config in (BusConfig(mode="client", connect=[plain], connect_timeout_s=2.0),
                           BusConfig(mode="client", connect=[where], tls_ca=str(gcs_ks.tls_ca), connect_timeout_s=2.0)):
                bus = opened(config, "anon")
                if bus is not None:  # (a session that opens must get nothing: it should not open at all)
                    try:
                        seen = Watch(bus)
                        time.sleep(1.0)
                        assert seen.got == {} and not bus.routers() and not bus.peers(), (where, seen.got)
                    finally:
                        bus.close()
        assert all(probe.fresh(u) for u in (1, 2, 3)), probe.last
        # revocation beside the running network, live at the launcher's gateway and edges (both reopen their sessions)
        assert keys_main(["revoke", str(tmp_path / "keys"), "uav2"]) == 0
        assert wait_until(lambda: not probe.fresh(2, within=2.0), 20), probe.last
        assert wait_until(lambda: probe.fresh(1) and probe.fresh(3), 20), probe.last
        assert wait_until(lambda: all(any("reopening the session" in ln for ln in net.group.get(f"uav{u}").lines)
                                      for u in (1, 3)), 20)  # the launcher's edges applied it too
        assert wait_until(lambda: probe.fresh(1) and probe.fresh(3), 20), probe.last
        assert not probe.answered(2) and probe.answered(1)
        time.sleep(2.0)
        assert not probe.fresh(2, within=2.0) and probe.fresh(1) and probe.fresh(3), probe.last
        # the ground station's signing key revoked beside it: the running edges refuse its next command at once
        signer, cmd1, ids = net.gcs_signer(), keys.cmd(FLEET, 1), itertools.count(100)

        def reason() -> str:
            r = probe.bus.request(cmd1, signer.sign(Hold(uav=1, cmd_id=next(ids)), cmd1), expect=CommandAck,
                                  timeout=1.0)
            return r.message.reason if r.ok else f"no answer: {r.error}"

        assert wait_until(lambda: not reason().startswith("no answer"), 10)
        assert "revoked" not in reason()
        assert keys_main(["revoke", str(tmp_path / "keys"), str(tmp_path / "keys" / "gcs" / "sign.pub")]) == 0
        assert wait_until(lambda: "revoked" in reason(), 10), reason()
    finally:
        if probe is not None:
            probe.close()
        net.stop()


def _copy_identity(ks_dir, node: str, folder):
    """A node's certificate, key and CA copied out of the key set (a stolen one, or a superseded one)."""
    import shutil

    folder.mkdir()
    for name in ("tls.pem", "tls.key"):
        shutil.copy(ks_dir / node / name, folder / name)
    shutil.copy(ks_dir / "ca.pem", folder / "ca.pem")
    return folder


def _as_uav2(cert_dir, where: list[str], mode: str) -> Bus | None:
    """A session with the uav2 certificate and key copied into ``cert_dir`` (a stolen or superseded one)."""
    return opened(BusConfig(mode=mode, connect=where, listen=[] if mode == "peer" else [],
                            tls_ca=str(cert_dir / "ca.pem"), tls_cert=str(cert_dir / "tls.pem"),
                            tls_key=str(cert_dir / "tls.key"), connect_timeout_s=3.0), "uav2")


def _speak_as_uav2(bus: Bus, seconds: float = 2.0) -> None:
    token = bus.token(keys.alive(FLEET, 2))
    pub = bus.publisher(keys.state(FLEET, 2), TELEMETRY)
    for i in range(int(seconds / 0.05)):
        pub.put(state(2, i))
        time.sleep(0.05)
    token.undeclare()


def _network(group, ks_dir, tag: str) -> tuple[list[str], list[str], object]:
    """A gateway and edge uav1 (its own listener) on the key set as it is now; their endpoints and uav1's process."""
    gw = [f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]
    edge1 = [f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]
    g = group.start(f"gateway-{tag}", ["gateway", "--fleet", FLEET, "--keys", str(ks_dir), "--listen", gw[0],
                                        "--state-ingress-hz", "0"])
    assert g.wait_ready(20), "\n".join(g.lines)
    e = group.start(f"uav1-{tag}", ["edge", "--uav", "1", "--home", "10,10,0", "--fleet", FLEET, "--keys",
                                    str(ks_dir), "--camera", "none", "--speed", "4", "--failsafe-timeout-s", "60",
                                    "--geofence", "0,0,0,100,100,40", "--connect", gw[0], "--listen", edge1[0]])
    assert e.wait_ready(30), "\n".join(e.lines)
    return gw, edge1, e


def test_a_revoked_node_is_refused_by_the_gateway_and_an_edge_and_a_reissued_one_admitted(tmp_path, group):
    """``skynet keys revoke DIR uav2``: after the restart, uav2's certificate gets nothing through the gateway and an
    edge ignores it; ``skynet keys reissue DIR uav2`` (same CA): the new certificate is admitted, the old one not."""
    from services.keys import main as keys_main

    ks_dir = init(tmp_path / "keys", uavs=3)
    stolen = _copy_identity(ks_dir, "uav2", tmp_path / "stolen")
    assert keys_main(["revoke", str(ks_dir), "uav2"]) == 0
    assert "uav2" not in KeySet(ks_dir, "gcs").admitted()

    def heard(gw: list[str], edge: list[str], uav1, cert_dir, tag: str) -> tuple[bool, bool]:
        """(the gateway passed uav2's states to the ground station, edge uav1 saw uav2 join) for ``cert_dir``."""
        before = len([ln for ln in uav1.lines if "UAV 2 joined" in ln])
        with Bus(tls(KeySet(ks_dir, "gcs"), "client", gw), FLEET, "gcs") as gcs:
            seen = Watch(gcs)
            time.sleep(0.5)
            for where, mode in ((gw, "client"), (edge, "peer")):
                bus = _as_uav2(cert_dir, where, mode)
                if bus is not None:
                    try:
                        _speak_as_uav2(bus)
                    finally:
                        bus.close()
            time.sleep(0.5)
            joined = wait_until(lambda: len([ln for ln in uav1.lines if "UAV 2 joined" in ln]) > before, 2)
            return 2 in seen.got, joined

    gw, edge1, uav1 = _network(group, ks_dir, "revoked")
    assert heard(gw, edge1, uav1, stolen, "revoked") == (False, False)
    assert keys_main(["reissue", str(ks_dir), "uav2"]) == 0
    admitted = KeySet(ks_dir, "gcs").admitted()
    assert "uav2.g2" in admitted and "uav2" not in admitted
    group.stop()  # restart: the nodes read the key set at start
    new = _copy_identity(ks_dir, "uav2", tmp_path / "new")
    again = ServiceGroup(echo=None)
    try:
        gw, edge1, uav1 = _network(again, ks_dir, "reissued")
        assert heard(gw, edge1, uav1, new, "new") == (True, True), uav1.lines[-10:]
        assert heard(gw, edge1, uav1, stolen, "old") == (False, False)
    finally:
        again.stop()


def test_a_router_presenting_a_node_certificate_is_refused_by_a_client(tmp_path, group):
    """A router that presents uav2's (valid, same fleet) certificate: the ground station's and the planner's dial
    fails at the handshake, while a router with the gateway's certificate is reached (the control)."""
    ks_dir = init(tmp_path / "keys", uavs=2)
    uav2 = KeySet(ks_dir, "uav2")
    impostor_ep = [f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]
    impostor = Bus(BusConfig(mode="router", listen=impostor_ep, tls_ca=str(uav2.tls_ca), tls_cert=str(uav2.tls_cert),
                             tls_key=str(uav2.tls_key)), FLEET, "impostor")
    real_ep = [f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"]
    gw = group.start("gateway", ["gateway", "--fleet", FLEET, "--keys", str(ks_dir), "--listen", real_ep[0]])
    assert gw.wait_ready(20), "\n".join(gw.lines)
    try:
        for role in ("gcs", "planner"):
            ks = KeySet(ks_dir, role)
            assert opened(tls(ks, "client", impostor_ep), role) is None, f"{role} reached a router holding uav2's cert"
            real = opened(tls(ks, "client", real_ep), role)
            assert real is not None and real.routers(), f"{role} did not reach the real gateway"
            real.close()
        # a UAV trusts both CAs (it accepts links from both kinds), and dials the gateway trusting the router CA alone
        from services.orchestration.trustmode import gateway_dial

        uav1 = KeySet(ks_dir, "uav1")
        bus = opened(tls(uav1, "peer", [gateway_dial(impostor_ep[0], ks_dir)]), "uav1")  # (a peer opens unlinked)
        if bus is not None:
            time.sleep(1.0)
            linked = bool(bus.routers())
            bus.close()
            assert not linked, "uav1 reached a router holding uav2's cert"
        real = opened(tls(uav1, "peer", [gateway_dial(real_ep[0], ks_dir)]), "uav1")
        assert real is not None and real.routers(), "uav1 did not reach the real gateway"
        real.close()
        assert gateway_dial("tcp/127.0.0.1:1", ks_dir) == "tcp/127.0.0.1:1"
        assert not impostor.session.info.transports(), "a client session reached the impostor"
    finally:
        impostor.close()


@pytest.mark.mission
def test_an_impaired_mission_behind_the_accept_guard_succeeds_with_tls_and_the_acl(impaired_secure_mission):
    """``skynet mission --impair all="after 4s delay 200ms"`` (the accept guard on by default), default secure mode, a key set of its
    own (tests/conftest.py, shared with the launcher's test of the plan under delay): the proxied links keep
    mutual TLS and the ACL on the gateway and on every edge, and the mission succeeds."""
    run = impaired_secure_mission
    assert run.proc.returncode == 0, run.failure()
    assert "plaintext" not in run.proc.stderr and "INSECURE" not in run.proc.stderr, run.failure()
    services = (run.out / "services.log").read_text()
    assert services.count("ACL by certificate common name") == 1, services[-3000:]  # the gateway
    assert services.count("mutual TLS as uav") == 3, services[-3000:]  # every edge, with its ACL
    assert "accept guard on" in services, services[-3000:]
    report = run.report()
    assert report["success"] and not report["failures"], report["failures"]


def test_the_memory_of_a_departed_identitys_declaration_flood_goes_back_to_the_system(tmp_path, group):
    """uav2's certificate declares 3,000 subscribers on new keys its grant admits, then leaves: the gateway's
    resident memory comes back down (Zenoh frees the entries; the allocator kept the pages)."""
    ks_dir = init(tmp_path / "keys", uavs=2)
    tls_ep = f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    gw = group.start("gateway", ["gateway", "--fleet", FLEET, "--keys", str(ks_dir), "--listen", tls_ep,
                                 "--period-s", "0.5"])
    assert gw.wait_ready(20), "\n".join(gw.lines)
    pid = gw.proc.pid
    base = settled_resident_mb(pid)
    uav2 = Bus(tls(KeySet(ks_dir, "uav2"), "client", [tls_ep]), FLEET, "uav2")
    try:
        held = [uav2.session.declare_subscriber(f"{keys.fleet_root(FLEET)}/uav/x{i}/state", lambda s: None)
                for i in range(3000)]
        grown = settled_resident_mb(pid) - base
    finally:
        uav2.close()
    time.sleep(2.0)  # the gateway notices the departure at its next period
    left = settled_resident_mb(pid) - base
    assert len(held) == 3000 and grown > 3.0, grown  # the flood took memory (about 3 KB a declaration)
    assert left < grown / 2, (grown, left)


def test_a_node_revoked_while_the_gateway_runs_is_cut_off_and_the_others_come_back(tmp_path, group):
    """``skynet keys revoke DIR uav2`` beside a running gateway: within seconds the stolen uav2 certificate's
    session (still open, still publishing) reaches nobody, while uav1's states reach the ground station again
    after the gateway reopened its router with the narrower ACL. A key set broken in between is logged once
    and changes nothing (no reopen, both still heard)."""
    from services.keys import main as keys_main

    ks_dir = init(tmp_path / "keys", uavs=2)
    tls_ep = f"tls/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    gw = group.start("gateway", ["gateway", "--fleet", FLEET, "--keys", str(ks_dir), "--listen", tls_ep,
                                 "--period-s", "0.5", "--state-ingress-hz", "0"])
    assert gw.wait_ready(20), "\n".join(gw.lines)
    gcs = Bus(tls(KeySet(ks_dir, "gcs"), "client", [tls_ep], reconnect_max_s=0.5), FLEET, "gcs")
    uav1 = Bus(tls(KeySet(ks_dir, "uav1"), "client", [tls_ep], reconnect_max_s=0.5), FLEET, "uav1")
    uav2 = Bus(tls(KeySet(ks_dir, "uav2"), "client", [tls_ep], reconnect_max_s=0.5), FLEET, "uav2")
    try:
        seen = Watch(gcs)
        pubs = {1: uav1.publisher(keys.state(FLEET, 1), TELEMETRY), 2: uav2.publisher(keys.state(FLEET, 2), TELEMETRY)}

        def speak(seconds: float) -> None:
            for i in range(int(seconds / 0.05)):
                for uav, pub in pubs.items():
                    pub.put(state(uav, i))
                time.sleep(0.05)

        speak(2.0)
        assert seen.got.get(1, 0) > 10 and seen.got.get(2, 0) > 10, seen.got  # both heard before
        certs = ks_dir / "certs.txt"
        good = certs.read_text()
        certs.write_text(good + "not a node\n")  # a key set the operator broke: the ACL stays as it is
        assert wait_until(lambda: any("key set unreadable" in ln and "not a node" in ln for ln in gw.lines), 10)
        seen.got.clear()
        speak(1.5)
        certs.write_text(good)
        assert seen.got.get(1, 0) > 10 and seen.got.get(2, 0) > 10, seen.got
        assert not any("reopening" in ln for ln in gw.lines), gw.lines[-10:]
        assert keys_main(["revoke", str(ks_dir), "uav2"]) == 0
        assert wait_until(lambda: any("revoked: uav2" in ln and "reopening" in ln for ln in gw.lines), 10), gw.lines[-10:]
        speak(4.0)  # the sessions come back to the reopened router
        seen.got.clear()
        speak(3.0)
        assert seen.got.get(1, 0) > 10 and 2 not in seen.got, seen.got
    finally:
        for bus in (gcs, uav1, uav2):
            bus.close()


def test_a_node_revoked_beside_a_running_edge_is_cut_off_at_the_edges_own_listener(tmp_path, group):
    """``skynet keys revoke DIR uav2`` beside a running edge: the stolen uav2 certificate's session at uav1's own
    listener (dialled directly, past the gateway) stops hearing uav1 within seconds and a new one hears nothing,
    while uav1's board goes on (its states, their sequence continuing, reach the ground station again)."""
    from services.keys import main as keys_main

    ks_dir = init(tmp_path / "keys", uavs=3)
    stolen = _copy_identity(ks_dir, "uav2", tmp_path / "stolen")
    gw, edge1, uav1 = _network(group, ks_dir, "live")
    thief = _as_uav2(stolen, edge1, "peer")
    assert thief is not None
    heard: list[int] = []
    seqs: list[int] = []
    try:
        thief.subscribe(keys.state(FLEET, 1), lambda m, s: heard.append(m.seq), expect=VehicleState, link=TELEMETRY)
        assert wait_until(lambda: len(heard) > 10, 10), "the stolen certificate did not reach uav1's listener"
        before = heard[-1]
        assert keys_main(["revoke", str(ks_dir), "uav2"]) == 0
        assert wait_until(lambda: any("reopening the session" in ln for ln in uav1.lines), 15), uav1.lines[-10:]
        assert wait_until(lambda: any("session reopened:" in ln and "were dropped" in ln for ln in uav1.lines), 10)
        time.sleep(1.0)
        n = len(heard)
        time.sleep(2.0)
        assert len(heard) == n, f"the revoked certificate still hears uav1 ({len(heard) - n} states)"
        again = _as_uav2(stolen, edge1, "peer")
        if again is not None:  # the TLS handshake passes (same CA); the ACL then denies it everything
            late: list[int] = []
            again.subscribe(keys.state(FLEET, 1), lambda m, s: late.append(m.seq), expect=VehicleState,
                            link=TELEMETRY)
            time.sleep(2.0)
            again.close()
            assert not late, f"a new session of the revoked certificate heard {len(late)} states"
        with Bus(tls(KeySet(ks_dir, "gcs"), "client", gw), FLEET, "gcs") as gcs:
            gcs.subscribe(keys.state(FLEET, 1), lambda m, s: seqs.append(m.seq), expect=VehicleState,
                          link=TELEMETRY)
            assert wait_until(lambda: len(seqs) > 10, 15), uav1.lines[-10:]
        assert min(seqs) > before, (before, seqs[:3])  # the same board: its sequence goes on
        assert not any("Traceback" in ln for ln in uav1.lines), uav1.lines[-20:]
    finally:
        thief.close()
