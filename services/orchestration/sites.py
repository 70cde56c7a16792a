"""Several gateways: a router mesh of sites, and who attaches where. Pure: no sockets, no bus.

Design notes: docs/multi-site.md (services/orchestration/sites.py).
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass, field

from edge.geometry.neighbourhood import FORMATION_SIZE, formation_index, formations

#: the private range the namespace links take their addresses from
VETH_NET = ipaddress.ip_network("10.18.0.0/16")
#: the router port every site's gateway listens on (each namespace has its own port space)
GATEWAY_PORT = 7447


@dataclass(frozen=True)
class Site:
    """One site: its gateway's name and the nodes attached to it."""

    index: int
    uavs: tuple[int, ...] = ()
    rcus: tuple[str, ...] = ()

    @property
    def gateway(self) -> str:
        return f"gw{self.index}"


@dataclass(frozen=True)
class Mesh:
    """The sites and the router links between their gateways (``(i, j)``, i < j: gateway j dials i)."""

    sites: tuple[Site, ...]
    links: tuple[tuple[int, int], ...] = field(default=())

    def site_of(self, node: str | int) -> int:
        """The site a UAV (by id) or an RCU (by name) attaches to."""
        for s in self.sites:
            if node in (s.uavs if isinstance(node, int) else s.rcus):
                return s.index
        raise KeyError(f"{node!r} is attached to no site")

    def peers_of(self, site: int) -> tuple[int, ...]:
        """The gateways gateway ``site`` dials (the lower-numbered ones)."""
        return tuple(i for i, j in self.links if j == site)


def site_of_uav(uav: int, sites: int, formation_size: int = FORMATION_SIZE) -> int:
    """The site of UAV ``uav``: its formation's index modulo the number of sites."""
    if not isinstance(sites, int) or sites < 1:
        raise ValueError(f"sites must be an int >= 1, got {sites!r}")
    return formation_index(uav, formation_size) % sites


def mesh(uavs: int, sites: int, rcus: dict[str, int] | None = None, formation_size: int = FORMATION_SIZE) -> Mesh:
    """Sites ``0..sites-1`` with UAVs ``1..uavs`` by formation and ``rcus`` (name -> site; default:
    every RCU at site 0), and a full mesh of router links.

    >>> m = mesh(6, 2, {"planner": 1})
    >>> [s.uavs for s in m.sites], m.links, m.site_of("planner")
    ([(1, 2, 3), (4, 5, 6)], ((0, 1),), 1)
    """
    if not isinstance(uavs, int) or not 0 <= uavs <= 255:
        raise ValueError(f"uavs must be an int in 0..255, got {uavs!r}")
    if not isinstance(sites, int) or not 1 <= sites <= 16:
        raise ValueError(f"sites must be an int in 1..16, got {sites!r}")
    rcus = dict(rcus or {})
    for name, s in rcus.items():
        if not isinstance(s, int) or not 0 <= s < sites:
            raise ValueError(f"RCU {name!r}: site {s!r} is not one of 0..{sites - 1}")
    members: list[list[int]] = [[] for _ in range(sites)]
    for u in range(1, uavs + 1):
        members[site_of_uav(u, sites, formation_size)].append(u)
    out = tuple(Site(k, tuple(members[k]), tuple(sorted(n for n, s in rcus.items() if s == k))) for k in range(sites))
    links = tuple((i, j) for j in range(sites) for i in range(j))
    return Mesh(out, links)


def check_sites(sites: int, uavs: int, formation_size: int = FORMATION_SIZE) -> int:
    """``--sites S`` checked against the fleet: at least one site, at most one per formation (a site
    without a formation would have a gateway and no UAV). ValueError with a one-line message."""
    if isinstance(sites, bool) or not isinstance(sites, int) or sites < 1:
        raise ValueError(f"--sites {sites!r}: at least one site (one gateway each)")
    n = len(formations(uavs, formation_size))
    if sites > n:
        raise ValueError(f"--sites {sites}: at most one site per formation ({uavs} UAVs fly as {n} "
                         f"formation{'s' if n != 1 else ''} of up to {formation_size})")
    return sites


def parse_rcu_sites(items: list[str] | tuple[str, ...], sites: int, names: list[str] | tuple[str, ...]
                    ) -> dict[str, int]:
    """Where each RCU of the run attaches: ``--rcu-site NAME=K`` items over the default site 0.

    ``names`` are the run's RCUs (``planner``, ``detector`` or ``detector-0..N-1``); ``detector``
    also names every instance ``detector-K`` at once; later items override earlier ones.
    ValueError names the bad item: no ``=``, an unknown RCU, a site outside ``0..sites-1``.

    >>> parse_rcu_sites(["detector=1", "detector-0=0"], 2, ["planner", "detector-0", "detector-1"])
    {'planner': 0, 'detector-0': 0, 'detector-1': 1}
    """
    out = {n: 0 for n in names}
    for item in items:
        name, sep, value = (part.strip() for part in item.partition("="))
        if not sep or not name or not value:
            raise ValueError(f"--rcu-site wants NAME=SITE, got {item!r}")
        try:
            site = int(value)
        except ValueError:
            site = -1
        if not 0 <= site < sites:
            raise ValueError(f"--rcu-site {item!r}: site {value!r} is not one of 0..{sites - 1} (--sites {sites})")
        targets = [n for n in names if n == name or (name == "detector" and n.startswith("detector-"))]
        if not targets:
            raise ValueError(f"--rcu-site {item!r}: no RCU {name!r} in this run (RCUs: {', '.join(names)})")
        for n in targets:
            out[n] = site
    return out


def gateway_process(site: int) -> str:
    """The launcher's process name of site ``site``'s gateway: ``gateway`` (site 0, what faults name), ``gateway-K``."""
    return "gateway" if site == 0 else f"gateway-{site}"


def veth_addresses(links: tuple[tuple[int, int], ...]) -> dict[tuple[int, int], tuple[str, str]]:
    """Per router link ``(i, j)`` the addresses of its two ends, ``(site i's, site j's)``, each a /30
    of :data:`VETH_NET` (link p: ``10.18.p/4.(4p+1)`` and ``+2``).

    >>> veth_addresses(((0, 1), (0, 2)))
    {(0, 1): ('10.18.0.1/30', '10.18.0.2/30'), (0, 2): ('10.18.0.5/30', '10.18.0.6/30')}
    """
    subnets = VETH_NET.subnets(new_prefix=30)
    out = {}
    for link in links:
        net = next(subnets)
        a, b = list(net.hosts())
        out[link] = (f"{a}/30", f"{b}/30")
    return out


def router_endpoint(address: str, port: int = GATEWAY_PORT) -> str:
    """The TCP endpoint of a gateway at ``address`` (a ``10.18.x.y/30`` interface address or a bare IP)."""
    return f"tcp/{address.split('/')[0]}:{port}"
