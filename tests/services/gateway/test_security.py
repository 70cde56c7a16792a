"""Authentication and access control at the gateway, end to end: the gateway started as
``python -m services.cli gateway --users FILE --acl``, the real planner, detector and two edges in
their own processes with their own credentials, and in-process sessions playing the ground
station, a third UAV and intruders. No mock of the bus."""

from __future__ import annotations

import re
import time

import cv2
import numpy as np
import pytest
import zenoh

from edge.surface import crack_image
from protocol import keys
from protocol.bus import PASSWORD_ENV, Bus, BusConfig, endpoint_address, multilink_endpoints
from protocol.imagery import pack_image
from protocol.links import COMMAND, IMAGERY, TELEMETRY
from protocol.messages import (
    CommandAck,
    DefectReport,
    Heartbeat,
    Hold,
    ImageMeta,
    Intrinsics,
    LinkStats,
    MissionPlan,
    Mode,
    PlanRequest,
    VehicleState,
)
from protocol.rtp import RtpSender, ssrc_for
from services.gateway.credentials import generate
from services.orchestration.process import ProcessGroup, free_port_pair
from tests.conftest import wait_until as _wait

FLEET = "sec"
USERS = ["uav1", "uav2", "uav3", "gcs", "planner", "detector", "visitor"]


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    """A secured network: gateway with --users/--acl, planner, detector, edges uav1 and uav2."""
    creds = generate(tmp_path_factory.mktemp("creds"), USERS)
    tcp, udp = free_port_pair()
    endpoints = multilink_endpoints("127.0.0.1", tcp, udp)
    connect = [a for e in endpoints for a in ("--connect", e)]
    groups: dict[str, ProcessGroup] = {}

    def start(name, args, password_on_command_line=False):
        # each service its own environment: the password travels in SKYNET_PASSWORD, not on the command line
        env = {} if password_on_command_line else {PASSWORD_ENV: creds.passwords[name]}
        g = groups[name] = ProcessGroup(echo=None, env=env)
        extra = [f"--password={creds.passwords[name]}"] if password_on_command_line else []
        return g.start(name, [*args, "--fleet", FLEET, "--multilink", "--user", name, *extra])

    # the gateway logs each denial (zenoh's access_control at debug level): shown when a test fails
    gw = ProcessGroup(echo=None, env={"RUST_LOG": "zenoh::net::routing::interceptor::access_control=debug"})
    groups["gateway"] = gw
    svc = gw.start("gateway", ["gateway", "--fleet", FLEET, "--multilink", "--period", "0.3",
                               "--users", str(creds.users_file), "--acl",
                               *[a for e in endpoints for a in ("--listen", e)]])
    try:
        assert svc.wait_for("router up", 20), "\n".join(svc.lines)
        services = {
            "planner": start("planner", ["planner", *connect], password_on_command_line=True),
            "detector": start("detector", ["detector", *connect]),
        }
        for uav, home in ((1, "10,10,0"), (2, "14,10,0")):
            # the edges accept each other with the UAVs' dictionary (credentials.mesh_config_doc)
            services[f"uav{uav}"] = start(f"uav{uav}", [
                "edge", "--uav", str(uav), *connect, "--listen", "tcp/127.0.0.1:0", "--config", str(creds.mesh_config),
                "--camera", "none", "--home", home, "--speed", "4", "--failsafe-timeout", "30",
                "--geofence", "0,0,0,100,100,40"])
        for name, s in services.items():
            assert s.wait_for(" up", 40), f"{name}:\n" + "\n".join(s.lines)
        yield {"endpoints": endpoints, "creds": creds, "services": services, "gateway": svc}
    finally:
        for g in groups.values():
            g.stop()


def _denials(net) -> list[str]:
    return [re.sub(r"\x1b\[[0-9;]*m", "", line)[-200:] for line in net["gateway"].lines if "unauthorized" in line][-10:]


def _client(net, user, password=None, connect=None, timeout=10.0):
    password = net["creds"].passwords[user] if password is None else password
    return Bus(BusConfig(mode="client", connect=connect or net["endpoints"], multilink=True, user=user,
                         password=password, connect_timeout_s=timeout), FLEET, user)


def _state(uav, seq=0, pos=(1.0, 2.0, 3.0)):
    return VehicleState(uav=uav, seq=seq, t=0.0, stamp=time.time(), pos=pos, vel=(0, 0, 0), att=(0, 0, 0),
                        rates=(0, 0, 0), mode=Mode.HOLD)


def test_wrong_or_missing_credentials_are_refused_at_connect(net):
    wrong = (("gcs", "not-the-password"), ("nobody", "whatever"), ("uav1", net["creds"].passwords["uav2"]))
    for user, password in wrong:
        with pytest.raises(zenoh.ZError):
            _client(net, user, password, timeout=1.0)
    with pytest.raises(zenoh.ZError):
        Bus(BusConfig(mode="client", connect=net["endpoints"], multilink=True, connect_timeout_s=1.0), FLEET, "anon")
    # a peer does not fail to open, but the gateway never lets it in
    with Bus(BusConfig(mode="peer", connect=net["endpoints"], user="uav1", password="wrong"), FLEET, "p") as peer:
        time.sleep(1.5)
        assert peer.routers() == []
    with _client(net, "gcs") as ok:
        assert ok.routers()
    # no password on the gateway's output
    out = "\n".join(net["gateway"].lines)
    assert not any(p in out for p in net["creds"].passwords.values())
    assert "authentication on: 7 users" in out and "visitor" in out  # the user without a role is named


def test_legitimate_flows_pass(net):
    states: dict[int, VehicleState] = {}
    with _client(net, "gcs") as gcs:
        gcs.subscribe(keys.state(FLEET, "*"), lambda m, s: states.__setitem__(m.uav, m), expect=VehicleState,
                      link=TELEMETRY)
        # state to the ground station, through the gateway; the edges hear each other (authenticated mesh)
        assert _wait(lambda: {1, 2} <= set(states) and all(states[u].neighbours >= 1 for u in (1, 2)), 20), \
            (states, _denials(net))
        # liveliness of every service
        alive = set(gcs.alive(keys.fleet_all(FLEET)))
        assert {keys.alive(FLEET, 1), keys.alive(FLEET, 2), keys.rcu_alive(FLEET, "planner"),
                keys.rcu_alive(FLEET, "detector")} <= alive, alive
        # command and acknowledgement
        ack = gcs.request(keys.cmd(FLEET, 1), Hold(uav=1, cmd_id=1), expect=CommandAck)
        assert ack.ok and ack.message.uav == 1 and ack.message.cmd_id == 1, (ack, _denials(net))
        # plan request and reply
        from services.planner.scenario import load_scenario

        req = PlanRequest(request_id=3, scenario=load_scenario(), particles=6, iterations=3)
        plan = gcs.request(keys.planner(FLEET), req, expect=MissionPlan, timeout=30)
        assert plan.ok and plan.message.request_id == 3, (plan.error, _denials(net))
        # the heartbeat reaches a UAV
        beats = []
        with _client(net, "uav3") as uav3:
            uav3.subscribe(keys.heartbeat(FLEET), lambda m, s: beats.append(m), expect=Heartbeat)
            hb = gcs.publisher(keys.heartbeat(FLEET), COMMAND)
            assert _wait(lambda: (hb.put(Heartbeat(seq=len(beats), stamp=time.time())) and False) or beats, 10)


def test_forbidden_messages_are_dropped(net):
    """A UAV cannot send the GCS heartbeat, another UAV's state or query another UAV's commands;
    the GCS cannot send a UAV state. Each forgery is checked next to a permitted message that got through."""
    seen_by_gcs: list = []
    seen_by_uav: list = []
    with _client(net, "gcs") as gcs, _client(net, "uav3") as uav3, _client(net, "visitor") as visitor:
        gcs.subscribe(keys.state(FLEET, 3), lambda m, s: seen_by_gcs.append(("state3", m.pos)), expect=VehicleState)
        gcs.subscribe(keys.state(FLEET, 1), lambda m, s: seen_by_gcs.append(("state1", m.pos)), expect=VehicleState)
        gcs.subscribe(keys.heartbeat(FLEET), lambda m, s: seen_by_gcs.append(("hb", m.seq)), expect=Heartbeat)
        uav3.subscribe(keys.state(FLEET, "*"), lambda m, s: seen_by_uav.append((m.uav, m.pos)), expect=VehicleState)
        time.sleep(1.0)
        own = uav3.publisher(keys.state(FLEET, 3), TELEMETRY)
        forged_state = uav3.publisher(keys.state(FLEET, 1), TELEMETRY)
        forged_hb = uav3.publisher(keys.heartbeat(FLEET), COMMAND)
        gcs_forged = gcs.publisher(keys.state(FLEET, 2), TELEMETRY)
        visitor_hb = visitor.publisher(keys.heartbeat(FLEET), COMMAND)
        marker = (66.0, 66.0, 66.0)
        for i in range(20):
            own.put(_state(3, i))
            forged_state.put(_state(1, i, pos=marker))
            forged_hb.put(Heartbeat(seq=1000 + i, stamp=time.time()))
            gcs_forged.put(_state(2, i, pos=marker))
            visitor_hb.put(Heartbeat(seq=2000 + i, stamp=time.time()))
            time.sleep(0.02)
        # the permitted message arrived, so the session was up while the forgeries were sent
        assert _wait(lambda: ("state3", (1.0, 2.0, 3.0)) in seen_by_gcs, 5), seen_by_gcs
        assert _wait(lambda: any(u == 1 for u, _ in seen_by_uav), 5)  # the real uav1's states reach uav3
        time.sleep(0.5)
        assert ("state1", marker) not in seen_by_gcs
        assert not [x for x in seen_by_gcs if x[0] == "hb"]
        assert (2, marker) not in seen_by_uav
        # a UAV (and a user without a role) cannot command another UAV; the GCS can
        assert not uav3.request(keys.cmd(FLEET, 1), Hold(uav=1, cmd_id=7), expect=CommandAck, timeout=1.0).ok
        assert not visitor.request(keys.cmd(FLEET, 2), Hold(uav=2, cmd_id=8), expect=CommandAck, timeout=1.0).ok
        assert gcs.request(keys.cmd(FLEET, 2), Hold(uav=2, cmd_id=9), expect=CommandAck).ok
    assert all(s.alive() for s in net["services"].values())


def _frame(sender, uav, cid, rng):
    grey, _ = crack_image((240, 320), rng, n_cracks=2)
    ok, jpeg = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 85])
    meta = ImageMeta(uav=uav, capture_id=cid, t=float(cid), stamp=time.time(), cam_pos=(10.0, 0.0, 20.0),
                     cam_rot=(1, 0, 0, 0, 0, 1, 0, -1, 0),
                     intrinsics=Intrinsics(width=320, height=240, fx=500, fy=500, cx=160, cy=120), range_m=5.0)
    return pack_image(sender, meta, jpeg.tobytes(), time.time())


def test_imagery_to_detector_with_recovery_and_defect_reports(net):
    """Camera frames over a lossy UDP link: the detector recovers the lost ones from the camera's
    cache (query/reply through the gateway) and the ground station gets a report for every frame."""
    from services.netem.proxy import UdpProxy

    tcp, udp = net["endpoints"]
    rng = np.random.default_rng(5)
    reports: dict[int, DefectReport] = {}
    with UdpProxy(("127.0.0.1", 0), endpoint_address(udp), "after 1s loss 20%", seed=11) as lossy:
        via = [tcp, f"udp/127.0.0.1:{lossy.port}?rel=0"]
        with _client(net, "gcs") as gcs, _client(net, "uav3", connect=via) as uav3:
            gcs.subscribe(keys.defects(FLEET), lambda m, s: reports.__setitem__(m.capture_id, m), expect=DefectReport)
            dstats = []
            gcs.subscribe(keys.rcu_stats(FLEET, "detector"), lambda m, s: dstats.append(m), expect=LinkStats)
            pub = uav3.publisher(keys.camera(FLEET, 3), IMAGERY, cache=64)
            time.sleep(1.2)  # the detector's subscription is known; the lossy onset comes after the UDP link is up
            sender = RtpSender(ssrc_for(3))
            for cid in range(30):
                pub.put_bytes(_frame(sender, 3, cid, rng))
                time.sleep(0.05)
            assert _wait(lambda: len(reports) == 30, 20), (sorted(set(range(30)) - set(reports)), _denials(net),
                                                           dstats[-1:])
        assert lossy.stats()["up"]["dropped"]["loss"] > 0  # frames were lost on the way ...
    assert all(r.ok and r.uav == 3 for r in reports.values())  # ... and recovered, each reported


def test_detector_instances_speak_on_their_own_keys_and_no_other_rcus(net):
    """the detector role may put statistics and hold a token as any instance (``detector-K``,
    services.detector.partition), and still not as the planner."""
    heard: list[tuple[str, str]] = []
    with _client(net, "gcs") as gcs, _client(net, "detector") as det:
        gcs.subscribe(keys.rcu_instances(FLEET, "detector", "stats"),
                      lambda m, s: heard.append((str(s.key_expr), m.source)), expect=LinkStats)
        gcs.subscribe(keys.rcu_stats(FLEET, "planner"), lambda m, s: heard.append((str(s.key_expr), m.source)),
                      expect=LinkStats)
        det.token(keys.rcu_alive(FLEET, "detector-1"))
        time.sleep(1.0)
        mine = det.publisher(keys.rcu_stats(FLEET, "detector-1"), TELEMETRY)
        forged = det.publisher(keys.rcu_stats(FLEET, "planner"), TELEMETRY)
        for _ in range(10):
            mine.put(LinkStats(source="detector-1", stamp=time.time(), uptime_s=1.0))
            forged.put(LinkStats(source="forged", stamp=time.time(), uptime_s=1.0))
            time.sleep(0.05)
        assert _wait(lambda: (keys.rcu_stats(FLEET, "detector-1"), "detector-1") in heard, 5), (heard, _denials(net))
        assert _wait(lambda: gcs.alive(keys.rcu_alive(FLEET, "detector-1")), 5), _denials(net)
        time.sleep(0.5)
    assert not [h for h in heard if h[1] == "forged"]
