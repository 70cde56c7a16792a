"""The links of a run and which of them carry an impairment proxy (pure: no sockets, no bus).

Design notes: docs/experiments.md (services/orchestration/topology.py).
"""

from __future__ import annotations

import copy
import hashlib
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

CLASSES = ("tcp", "udp")
GROUPS = ("uplinks", "skynet", "all")
SERVICES = ("planner", "detector", "gcs")
MeshMode = Literal["direct", "proxied"]

_UAV = re.compile(r"uav([1-9][0-9]*)")
_PAIR = re.compile(r"uav([1-9][0-9]*)-uav([1-9][0-9]*)")


def skynet_link(i: int, j: int) -> str:
    """The name of the SkyNet link between edges ``i`` and ``j`` (lower id first)."""
    if i == j:
        raise ValueError(f"a SkyNet link joins two different UAVs, got uav{i}-uav{j}")
    a, b = sorted((i, j))
    return f"uav{a}-uav{b}"


def link_ends(name: str) -> tuple[int, int] | None:
    """``(i, j)`` of a SkyNet link name, None for an uplink name."""
    m = _PAIR.fullmatch(name)
    return (int(m.group(1)), int(m.group(2))) if m else None


@dataclass(frozen=True)
class Links:
    """The links of one run: the nodes that have an uplink and the UAV ids of the mesh."""

    uavs: int
    services: tuple[str, ...] = SERVICES

    @property
    def edges(self) -> list[str]:
        return [f"uav{i}" for i in range(1, self.uavs + 1)]

    @property
    def uplinks(self) -> list[str]:
        return [*self.edges, *self.services]

    @property
    def skynet(self) -> list[str]:
        """The SkyNet links: between the UAVs of each formation (:mod:`edge.geometry.neighbourhood`), not across."""
        from edge.geometry.neighbourhood import formations

        return [skynet_link(i, j) for f in formations(self.uavs) for i in f for j in f if j > i]

    def uav(self, text: str, what: str = "name") -> int:
        """The id of ``uavN``, checked against the fleet size."""
        m = _UAV.fullmatch(text)
        if not m:
            raise ValueError(f"{what} {text!r}: expected uavN")
        n = int(m.group(1))
        if not 1 <= n <= self.uavs:
            raise ValueError(f"{what} {text!r}: there are {self.uavs} UAVs (uav1..uav{self.uavs})")
        return n

    def resolve(self, name: str) -> list[str]:
        """The links a name stands for (a link, a group); ValueError naming the bad name."""
        name = name.strip()
        if name == "uplinks":
            return self.uplinks
        if name == "skynet":
            return self.skynet
        if name == "all":
            return [*self.uplinks, *self.skynet]
        if name in self.services:
            return [name]
        if name in SERVICES:
            raise ValueError(f"link {name!r}: no {name} in this run (it connects on its own)")
        pair = _PAIR.fullmatch(name)
        if pair:
            i, j = (self.uav(f"uav{g}", "link") for g in pair.groups())
            if skynet_link(i, j) not in self.skynet:
                raise ValueError(f"link {name!r}: uav{i} and uav{j} fly in different formations "
                                 "(SkyNet links only join UAVs of one formation)")
            return [skynet_link(i, j)]
        if _UAV.fullmatch(name):
            return [f"uav{self.uav(name, 'link')}"]
        raise ValueError(f"link {name!r}: expected uavN, uavI-uavJ, {', '.join(self.services)}, "
                         f"{', '.join(GROUPS)}")


@dataclass
class Impairments:
    """``specs[link][class]``: the netem string of each impaired link class (absent = clean)."""

    specs: dict[str, dict[str, str]] = field(default_factory=dict)

    def spec(self, link: str, cls: str) -> str | None:
        return self.specs.get(link, {}).get(cls)

    def links(self) -> list[str]:
        return list(self.specs)

    def worst_delay_ms(self) -> float:
        """The largest one-way delay any impaired link adds (delay + 3 jitter, its rate's
        serialisation of a 64 KB datagram aside), ms; 0 with no impairment."""
        from services.netem.model import Impairment

        worst = 0.0
        for classes in self.specs.values():
            for spec in classes.values():
                imp = Impairment.parse(spec)
                worst = max(worst, imp.delay_ms + 3.0 * imp.jitter_ms)
        return worst


def parse_impair(items: Iterable[str], links: Links) -> Impairments:
    """Read ``--impair [NAME[/udp|/tcp]=]SPEC`` items (:func:`services.netem.model.parse_impair_arg`; no NAME:
    every link, ``all``); later ones override earlier ones.

    Raises ValueError with a one-line message naming the bad item (unknown link, unknown class,
    an empty or invalid SPEC).
    """
    from services.netem.model import parse_impair_arg

    out = Impairments()
    for item in items:
        arg = parse_impair_arg(item)
        try:
            targets = links.resolve(arg.link or "all")
        except ValueError as e:
            raise ValueError(f"--impair {item!r}: {e}") from None
        for link in targets:
            for c in ([arg.cls] if arg.cls else CLASSES):
                out.specs.setdefault(link, {})[c] = arg.spec
    return out


def link_seed(seed: int, link: str, cls: str) -> int:
    """A proxy's seed: distinct per link and class, the same in every run with the same ``seed``
    (a hash, not Python's randomised ``hash()``)."""
    digest = hashlib.sha256(f"{seed}/{link}/{cls}".encode()).digest()
    return int.from_bytes(digest[:8], "big")


#: ``transport/unicast/open_timeout`` of the edges, ms (zenoh's default 10 000). An edge dials
#: the UDP endpoint of a neighbour that may not be up yet (edges start together, or one restarts
#: after a fault); the unanswered handshake is retried only after this timeout, so with the
#: default the SkyNet pair ran TCP-only for 10 s (measured: 5 runs of 3 edges, 1-2 of 3 UDP links
#: late by ~10 s in 3 of them). 2.5 s still leaves room for a handshake (two round trips) over a
#: link with hundreds of ms of delay.
OPEN_TIMEOUT_MS = 2500


def open_timeout_ms(worst_delay_ms: float) -> int:
    """:data:`OPEN_TIMEOUT_MS` plus four round trips of the worst one-way delay: opening a zenoh
    link takes the TCP handshake and two more round trips (InitSyn/Ack, OpenSyn/Ack), and a link
    that cannot open in time is abandoned and dialled again, over and over (200 ms each way: 4.1 s)."""
    return int(OPEN_TIMEOUT_MS + 8.0 * max(0.0, worst_delay_ms))


def edge_mesh_config(mesh: MeshMode, base: dict | None = None, open_timeout: int = OPEN_TIMEOUT_MS) -> dict:
    """The zenoh config of an edge whose links must all go where the launcher points them: gossip's autoconnect
    never to the router and to peers only with the ``direct`` mesh (docs/experiments.md,
    services/orchestration/topology.py); ``base`` (e.g. a config file of the user's) merged in; the open timeout
    shortened (:data:`OPEN_TIMEOUT_MS`, more on slow links: :func:`open_timeout_ms`)."""
    doc = copy.deepcopy(base or {})
    peer = ["peer"] if mesh == "direct" else []
    return _merge(doc, {"scouting": {"gossip": {"autoconnect": {"router": [], "peer": peer}}},
                        "transport": {"unicast": {"open_timeout": open_timeout}}})


def _merge(into: dict, other: dict) -> dict:
    for k, v in other.items():
        if isinstance(v, dict) and isinstance(into.get(k), dict):
            _merge(into[k], v)
        else:
            into[k] = v
    return into
