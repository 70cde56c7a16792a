"""The launcher's links with real processes: SkyNet through proxies, faults on a running network.

Each test starts a whole ``skynet up``-like :class:`~services.orchestration.launcher.Network` in this process (gateway,
three edges, planner, detector as child processes; the proxies in this process) and watches it from a
probe client session on the gateway, as a ground station would. Edges' ``neighbours`` (states heard over
SkyNet) and their ``neighbour-up``/``neighbour-lost`` log lines (liveliness) tell what each edge sees.
"""

from __future__ import annotations

import logging
import threading
import time

import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.links import LINK_LEASE_S, TELEMETRY
from protocol.messages import Hold, VehicleState
from services.orchestration.launcher import Network, parse
from tests.conftest import wait_until

#: the edges' link lease (edge.board: --lease-s defaults to it)
EDGE_LEASE_S = LINK_LEASE_S


class Probe:
    """A client session on the gateway (connected as the ground station is: mutual TLS when the network
    runs secure): the latest state of each UAV and the UAVs' liveliness."""

    def __init__(self, config: BusConfig, fleet: str):
        self.fleet = fleet
        self.bus = Bus(config, fleet, "probe")
        self.lock = threading.Lock()
        self.last: dict[int, tuple[int, float]] = {}  # uav -> (neighbours, rx wall time)
        self.alive: dict[int, bool] = {}
        self.bus.subscribe(keys.state(fleet, "*"), self._on_state, expect=VehicleState, link=TELEMETRY)
        self.bus.watch_alive(keys.alive(fleet, "*"), self._on_alive)

    def _on_state(self, msg, sample) -> None:
        with self.lock:
            self.last[msg.uav] = (msg.neighbours, time.time())

    def _on_alive(self, key: str, alive: bool) -> None:
        self.alive[keys.parse(key).uav] = alive

    def fresh(self, uav: int, within: float = 0.5) -> bool:
        with self.lock:
            got = self.last.get(uav)
        return got is not None and time.time() - got[1] < within

    def neighbours(self, uav: int) -> int | None:
        """What uav says it hears over SkyNet, if its state is fresh."""
        with self.lock:
            got = self.last.get(uav)
        return got[0] if got is not None and time.time() - got[1] < 0.5 else None

    def answered(self, uav: int) -> bool:
        """A command reaches the edge and comes back (any reply from the board, even a refusal)."""
        r = self.bus.request(keys.cmd(self.fleet, uav), Hold(uav=uav, cmd_id=1), timeout=1.0)
        return r.ok or not (r.error.startswith("no reply") or r.error.startswith("query failed")
                            or "Timeout" in r.error)

    def close(self) -> None:
        self.bus.close()


def network(fleet: str, *extra: str) -> Network:
    args = parse("up", ["--speed", "8", "--fleet", fleet, "--camera", "none", *extra])
    return Network(args, echo=None)


def lines(net: Network, name: str, text: str) -> list[str]:
    return [ln for ln in list(net.group.get(name).lines) if text in ln]


@pytest.fixture
def running():
    """Start a network (``running(fleet, *args)``) with a probe on its gateway; both stopped after the test."""
    started: list[tuple[Network, Probe]] = []

    def start(fleet: str, *extra: str) -> tuple[Network, Probe]:
        net = network(fleet, *extra)
        started.append((net, None))
        net.start()
        probe = Probe(net.gcs_config(), fleet)
        started[-1] = (net, probe)
        return net, probe

    yield start
    for net, probe in started:
        if probe is not None:
            probe.close()
        net.stop()


def test_proxied_skynet_carries_the_mesh_and_a_cut_separates_two_edges(running):
    net, probe = running("topo", "--mesh", "proxied")
    assert net.plan.mesh == "proxied" and set(net.proxies) == {"uav1-uav2", "uav1-uav3", "uav2-uav3"}
    # every edge hears both others over SkyNet (states) and saw them join (liveliness)
    assert wait_until(lambda: all(probe.neighbours(u) == 2 for u in (1, 2, 3)), 30), probe.last
    for u in (1, 2, 3):
        for v in {1, 2, 3} - {u}:
            assert wait_until(lambda u=u, v=v: lines(net, f"uav{u}", f"UAV {v} joined SkyNet"), 5), (u, v)
    # all edge-edge traffic crosses the proxies, on both the reliable (TCP) and best-effort (UDP) link:
    # states are best-effort, so UDP carries most of it once zenoh's UDP links are open
    def both_ways(link: str, cls: str, least: int) -> bool:
        st = net.proxies[link][cls].stats()
        return st["up"]["sent_bytes"] > least and st["down"]["sent_bytes"] > least

    for link in net.proxies:
        assert wait_until(lambda link=link: both_ways(link, "udp", 5000), 15), (link, net.proxies[link]["udp"].stats())
        assert both_ways(link, "tcp", 100), (link, net.proxies[link]["tcp"].stats())

    # cut uav1-uav2: the two lose each other (the gateway does not relay between peers), uav3 keeps both,
    # and both still reach the gateway
    for p in net.link_proxies("uav1-uav2"):
        p.cut()
    assert wait_until(lambda: probe.neighbours(1) == 1 and probe.neighbours(2) == 1, 10), probe.last
    assert wait_until(lambda: lines(net, "uav1", "UAV 2 left SkyNet") and lines(net, "uav2", "UAV 1 left SkyNet"),
                      3 * EDGE_LEASE_S)
    time.sleep(1.0)
    assert probe.neighbours(1) == 1 and probe.neighbours(2) == 1 and probe.neighbours(3) == 2, probe.last
    assert probe.fresh(1) and probe.fresh(2) and probe.answered(1) and probe.answered(2)
    # healed: they find each other again through the same proxies
    t0 = time.monotonic()
    for p in net.link_proxies("uav1-uav2"):
        p.restore()
    assert wait_until(lambda: all(probe.neighbours(u) == 2 for u in (1, 2, 3)), 30), probe.last
    print(f"\nSkyNet link uav1-uav2 healed: states shared again {time.monotonic() - t0:.2f} s after the restore")


def test_gateway_killed_and_restarted_on_the_same_ports(running):
    net, probe = running("gwkill", "--fault", "0s kill gateway for 2s")
    assert wait_until(lambda: all(probe.neighbours(u) == 2 for u in (1, 2, 3)), 30), probe.last
    gw_pid = net.group.get("gateway").proc.pid
    injector = net.start_faults(logging.getLogger("test"))
    injector.start(origin=time.time())
    assert wait_until(lambda: len(injector.ledger) == 1, 5)
    assert not net.group.get("gateway").alive()
    # while the gateway is down, the edges keep flying over SkyNet
    time.sleep(1.0)
    assert not any(probe.fresh(u) for u in (1, 2, 3))
    assert all(lines(net, f"uav{u}", "left SkyNet") == [] for u in (1, 2, 3))
    assert wait_until(lambda: len(injector.ledger) == 2, 40), injector.ledger
    restarted = time.monotonic()
    gw = net.group.get("gateway")
    assert gw.alive() and gw.proc.pid != gw_pid and gw.restarts == 1
    assert injector.ledger[1][1] == "restart" and "up again" in injector.ledger[1][3]
    # the edges and the client session see each other again, through the same endpoints
    assert wait_until(lambda: all(probe.fresh(u, 0.3) and probe.neighbours(u) == 2 for u in (1, 2, 3)), 30)
    assert all(wait_until(lambda u=u: probe.answered(u), 30) for u in (1, 2, 3))
    print(f"\ngateway restart: {injector.ledger[1][3]}; fleet seen by the client again "
          f"{time.monotonic() - restarted:.2f} s after it was up")
    assert net.check_alive() == []


def test_killed_edge_is_seen_gone_within_its_lease_and_comes_back(running):
    net, probe = running("edgekill", "--fault", "0s kill uav3 for 3s")
    assert wait_until(lambda: all(probe.neighbours(u) == 2 for u in (1, 2, 3)), 30), probe.last
    assert wait_until(lambda: probe.alive.get(3) is True, 5)
    injector = net.start_faults(logging.getLogger("test"))
    injector.start(origin=time.time())
    assert wait_until(lambda: injector.ledger, 5)
    killed = time.monotonic()
    assert wait_until(lambda: lines(net, "uav1", "UAV 3 left SkyNet") and lines(net, "uav2", "UAV 3 left SkyNet")
                      and probe.alive.get(3) is False, EDGE_LEASE_S + 3.0)
    print(f"\nuav3 killed: seen gone by uav1, uav2 and the client within {time.monotonic() - killed:.2f} s "
          f"(lease {EDGE_LEASE_S} s)")
    assert net.check_alive() == []  # killed on purpose is not a failure
    assert wait_until(lambda: probe.neighbours(1) == 1 and probe.neighbours(2) == 1, 5), probe.last
    # restarted with the same command line: back on SkyNet and on the gateway
    assert wait_until(lambda: len(injector.ledger) == 2, 40), injector.ledger
    back = time.monotonic()
    assert wait_until(lambda: all(probe.neighbours(u) == 2 for u in (1, 2, 3)), 30), probe.last
    assert probe.alive.get(3) is True
    print(f"uav3 restarted ({injector.ledger[1][3]}): mesh whole again {time.monotonic() - back:.2f} s later")


def test_uplinks_cut_longer_than_the_lease_come_back_after_the_restore(running):
    net, probe = running("uplinkcut", "--fault", "0s cut uplinks for 3s")
    assert set(net.proxies) == {"uav1", "uav2", "uav3"} and net.plan.mesh == "direct"
    assert wait_until(lambda: all(probe.neighbours(u) == 2 for u in (1, 2, 3)), 30), probe.last
    injector = net.start_faults(logging.getLogger("test"))
    injector.start(origin=time.time())
    assert wait_until(lambda: injector.ledger, 5)
    time.sleep(2.5)  # past the lease: the gateway has dropped the edges, and they it
    assert not any(probe.fresh(u) for u in (1, 2, 3))
    assert wait_until(lambda: len(injector.ledger) == 2, 5), injector.ledger
    restored = time.monotonic()
    # the edges kept their SkyNet mesh meanwhile and reopen their sessions with the gateway
    assert wait_until(lambda: all(probe.fresh(u, 0.3) and probe.neighbours(u) == 2 for u in (1, 2, 3)), 30), \
        probe.last
    print(f"\nuplinks cut 3 s: the client sees the fleet again {time.monotonic() - restored:.2f} s after the restore")
    assert all(probe.answered(u) for u in (1, 2, 3))


def test_open_timeout_grows_with_the_worst_configured_delay():
    from services.orchestration.topology import OPEN_TIMEOUT_MS, Links, open_timeout_ms, parse_impair

    links = Links(3, ("planner", "detector", "gcs"))
    assert parse_impair([], links).worst_delay_ms() == 0.0
    imp = parse_impair(["uav2=delay 50ms", "all/udp=after 2s delay 200ms jitter 20ms loss 20%"], links)
    assert imp.worst_delay_ms() == 260.0  # delay + 3 jitter
    assert open_timeout_ms(0.0) == OPEN_TIMEOUT_MS
    assert open_timeout_ms(imp.worst_delay_ms()) == OPEN_TIMEOUT_MS + 8 * 260


def test_skynet_links_join_only_the_uavs_of_one_formation():
    from services.orchestration.topology import Links

    assert Links(3).skynet == ["uav1-uav2", "uav1-uav3", "uav2-uav3"]
    six = Links(6).skynet
    assert six == ["uav1-uav2", "uav1-uav3", "uav2-uav3", "uav4-uav5", "uav4-uav6", "uav5-uav6"]
    assert len(Links(99).skynet) == 3 * 33  # linear in the fleet, not N(N-1)/2
    assert Links(6).resolve("uav4-uav6") == ["uav4-uav6"]
    with pytest.raises(ValueError, match="different formations"):
        Links(6).resolve("uav1-uav4")
