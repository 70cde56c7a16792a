"""Two gateways in two network namespaces (stand-ins for two hosts), a router link between them over a
veth pair, the RCU and the UAVs attached to either. Real processes, real Zenoh routing.

Site 0: gateway gw0 and UAV 1; site 1: gateway gw1, UAV 4 and the planner. gw1 dials gw0 at 10.18.0.1
through the project's user-space impairment proxy (``skynet netem tcp``, in site 1's namespace: the
stand-in for a slow link between two hosts), which delays the router link by 50 ms each way. The
ground station (this test, in the machine's own namespace) attaches to gw0 through a Unix socket. It
must hear both UAVs' states, command UAV 4 and get a plan from the planner: every one of those
crosses the router link, so UAV 4's states arrive later than UAV 1's by the proxy's delay.
"""

import os
import statistics
import subprocess
import time
from pathlib import Path

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.links import TELEMETRY
from protocol.messages import CommandAck, MissionPlan, PlanRequest, Takeoff, VehicleState
from services.orchestration.netns import Namespaces, available
from services.orchestration.process import ProcessGroup
from services.orchestration.sites import GATEWAY_PORT, mesh, router_endpoint
from services.planner.scenario import load_scenario
from tests.conftest import wait_until
from tests.readiness import wait_ready

FLEET = "sites"
OK, WHY = available()
pytestmark = [pytest.mark.root, pytest.mark.skipif(not OK, reason=f"no network namespaces here: {WHY}")]
PROXY_PORT = GATEWAY_PORT + 10  # in site 1's namespace: its own port space
DELAY_MS = 50


def test_two_gateways_across_namespaces_route_states_commands_and_plans(tmp_path: Path):
    m = mesh(6, 2, {"planner": 1})
    sock = tmp_path / "gw0.sock"
    local = f"tcp/127.0.0.1:{GATEWAY_PORT}"
    with Namespaces(m) as ns:
        groups = [ProcessGroup(echo=None, prefix=ns.prefix(s.index)) for s in m.sites]
        try:
            gw0 = groups[0].start("gw0", ["gateway", "--id", "gw0", "--fleet", FLEET,
                                          "--listen", f"tcp/0.0.0.0:{GATEWAY_PORT}", "--listen", f"unixsock-stream/{sock}"],
                                  ready=True)
            gw0_addr = router_endpoint(ns.address(0, 1)).removeprefix("tcp/")
            proxy = groups[1].start("netem", ["netem", "tcp", "--listen", f"127.0.0.1:{PROXY_PORT}", "--target",
                                              gw0_addr, "--impair", f"delay {DELAY_MS}ms", "--interval-s", "1"],
                                     ready=True)
            wait_ready(proxy)
            gw1 = groups[1].start("gw1", ["gateway", "--id", "gw1", "--fleet", FLEET, "--listen",
                                          f"tcp/0.0.0.0:{GATEWAY_PORT}", "--connect", f"tcp/127.0.0.1:{PROXY_PORT}"],
                                  ready=True)
            for g in (gw0, gw1):
                wait_ready(g, 90)
            nodes = [groups[1].start("planner", ["planner", "--fleet", FLEET, "--mode", "client", "--connect", local],
                                     ready=True)]
            for uav in (1, 4):
                site = m.site_of(uav)
                nodes.append(groups[site].start(f"uav{uav}", [
                    "edge", "--uav", str(uav), "--fleet", FLEET, "--camera", "none", "--connect", local,
                    "--home", f"{10 * uav},10,0", "--geofence", "0,0,0,100,100,40"], ready=True))
            for n in nodes:
                wait_ready(n, 90)

            states: dict[int, VehicleState] = {}
            ages: dict[int, list[float]] = {1: [], 4: []}

            def on_state(msg: VehicleState, _sample) -> None:
                states[msg.uav] = msg
                ages.setdefault(msg.uav, []).append(time.time() - msg.stamp)

            with Bus(BusConfig(mode="client", connect=[f"unixsock-stream/{sock}"]), FLEET, "gcs") as gcs:
                gcs.subscribe(keys.state(FLEET, "*"), on_state, expect=VehicleState, link=TELEMETRY)
                assert wait_until(lambda: {1, 4} <= set(states), 30), states  # UAV 4's cross gw1 -> gw0
                ack = gcs.request(keys.cmd(FLEET, 4), Takeoff(uav=4, cmd_id=1, altitude=5), expect=CommandAck,
                                  timeout=10)
                assert ack.ok and ack.message.accepted, ack
                req = PlanRequest(request_id=1, scenario=load_scenario(), particles=10, iterations=5)
                plan = gcs.request(keys.planner(FLEET), req, expect=MissionPlan, timeout=60)
                assert plan.ok and len(plan.message.trajectories) == 3, plan
                # UAV 4 climbs (its states, routed through both gateways, say so)
                assert wait_until(lambda: states[4].pos[2] > 1.0, 30), states[4]
            # UAV 4's states cross the impaired router link, UAV 1's do not (one clock: this machine's)
            extra_ms = 1e3 * (statistics.median(ages[4][-100:]) - statistics.median(ages[1][-100:]))
            assert 0.8 * DELAY_MS <= extra_ms <= 3 * DELAY_MS, (extra_ms, len(ages[1]), len(ages[4]))
        finally:
            for g in reversed(groups):
                g.stop()


def _netns_of(pid: int) -> str:
    return os.readlink(f"/proc/{pid}/ns/net")


def test_the_launcher_runs_each_site_in_a_namespace_of_its_own():
    """``skynet up --sites 2 --netns`` (secure, the default): each site's gateway, edges and RCUs in the site's
    namespace, the router link through the project's proxy over the veth, and site 0 reached from the
    machine's own namespace through the Unix socket bridges with the ground station's certificate: this test
    hears all six UAVs (formation 2's through the router link) and both gateways' statistics."""
    from protocol.messages import LinkStats
    from services.orchestration.launcher import Network, parse

    args = parse("up", ["--fleet", "netns", "--uavs", "6", "--sites", "2", "--netns",
                                          "--rcu-site", "planner=1", "--speed", "4"])
    net = Network(args, echo=None)
    try:
        net.start()
        g = net.group
        for i in range(1, 7):
            wait_ready(g.get(f"uav{i}"), 60)
        here = _netns_of(os.getpid())
        site0, site1 = _netns_of(g.get("gateway").proc.pid), _netns_of(g.get("gateway-1").proc.pid)
        assert len({here, site0, site1}) == 3
        assert [_netns_of(g.get(f"uav{i}").proc.pid) for i in range(1, 7)] == [site0] * 3 + [site1] * 3
        assert _netns_of(g.get("planner").proc.pid) == site1 and _netns_of(g.get("detector").proc.pid) == site0
        links = [s for s in g.services if s.name.startswith("link-gateway-1-gateway-")]
        assert len(links) == 1 and all(_netns_of(s.proc.pid) == site1 for s in links)  # one link per router link
        states: dict[int, float] = {}
        stats: dict[str, LinkStats] = {}
        with Bus(net.gcs_config(), "netns", "gcs") as gcs:
            gcs.subscribe(keys.state("netns", "*"), lambda m, s: states.__setitem__(m.uav, m.stamp),
                          expect=VehicleState, link=TELEMETRY)
            gcs.subscribe(keys.gateway_stats("netns"), lambda m, s: stats.__setitem__(m.source, m),
                          expect=LinkStats, link=TELEMETRY)
            assert wait_until(lambda: set(states) == set(range(1, 7)), 60), states
            assert wait_until(lambda: {"gateway/gw0", "gateway/gw1"} <= set(stats)
                              and all(s.sessions.get("router") == 1 for s in stats.values()), 30), stats
    finally:
        net.stop()
    assert net.ns is not None and not any(n in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                                              text=True).stdout for n in net.ns.names)
