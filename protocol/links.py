"""The paper's three link classes, one definition each (the paper's Section 1).

Design notes: docs/bus.md (protocol/links.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import zenoh

Congestion = Literal["block", "drop", "block_first"]

#: the link lease of the UAVs' boards and, when links are proxied or stall, of every node on the other end of
#: their links (``transport/link/tx/lease``), s. A UAV that drops off silently is seen gone after it (its
#: liveliness token lapses). Each side of a zenoh link declares it dead after the *other* side's lease without news: with
#: zenoh's 10 s on the gateway, an uplink cut for 3 s left the edges on their old session while the gateway had
#: already dropped it, and the gateway then refused their data ("Route data with unknown scope") for good;
#: with equal leases both sides drop the session and reopen.
LINK_LEASE_S = 2.0


@dataclass(frozen=True)
class LinkClass:
    name: str
    reliable: bool
    congestion: Congestion
    priority: str  # zenoh.Priority member name: REAL_TIME ... DATA ... BACKGROUND
    express: bool

    def publisher_qos(self) -> dict[str, Any]:
        """Keyword arguments for ``Session.declare_publisher``."""
        return {"reliability": zenoh.Reliability.RELIABLE if self.reliable else zenoh.Reliability.BEST_EFFORT,
                "congestion_control": _CONGESTION[self.congestion], "priority": getattr(zenoh.Priority, self.priority),
                "express": self.express}

    def request_qos(self) -> dict[str, Any]:
        """Keyword arguments for ``Session.get`` (queries have no reliability knob)."""
        return {"congestion_control": _CONGESTION[self.congestion], "priority": getattr(zenoh.Priority, self.priority),
                "express": self.express}


_CONGESTION = {"block": zenoh.CongestionControl.BLOCK, "drop": zenoh.CongestionControl.DROP,
               "block_first": zenoh.CongestionControl.BLOCK_FIRST}

COMMAND = LinkClass("command", reliable=True, congestion="block", priority="INTERACTIVE_HIGH", express=False)
TELEMETRY = LinkClass("telemetry", reliable=False, congestion="drop", priority="DATA_HIGH", express=True)
IMAGERY = LinkClass("imagery", reliable=False, congestion="drop", priority="DATA_LOW", express=False)
#: imagery too large for one UDP datagram (a 12 MP JPEG is about 600 KB, some ten datagrams,
#: and losing any one loses the frame, even on a clean loopback): the same class on the reliable link
IMAGERY_RELIABLE = LinkClass("imagery", reliable=True, congestion="block", priority="DATA_LOW", express=False)

LINK_CLASSES: dict[str, LinkClass] = {c.name: c for c in (COMMAND, TELEMETRY, IMAGERY)}


def class_of_topic(topic: str) -> LinkClass:
    """The link class a key-space topic travels on (see :mod:`protocol.keys`)."""
    if topic in ("state", "stats"):
        return TELEMETRY
    if topic in ("camera", "preview"):
        return IMAGERY
    return COMMAND


def transports(endpoints: list[str]) -> dict[str, str]:
    """The protocol (``tls``, ``tcp``, ``udp``, ...) each class rides on a session connected to ``endpoints``: with
    multilink, the reliable class on the ``rel=1`` endpoint and the best-effort class on the ``rel=0`` one; else
    both on the first. Empty when there is no endpoint.

    >>> transports(["tls/h:1?rel=1", "tls/h:2?rel=0"]), transports(["tcp/h:1?rel=1", "udp/h:2?rel=0"])
    ({'reliable': 'tls', 'best-effort': 'tls'}, {'reliable': 'tcp', 'best-effort': 'udp'})
    """
    if not endpoints:
        return {}

    def scheme(rel: str) -> str:
        return next((e for e in endpoints if f"rel={rel}" in e.partition("?")[2]), endpoints[0]).partition("/")[0]

    return {"reliable": scheme("1"), "best-effort": scheme("0")}
