"""Per-identity declaration caps at the gateway, read from the router's admin space (pure).

Zenoh 1.10 bounds sessions, links, message sizes and put rates, and its ACL decides *which* key expressions a
subject may declare, but nothing bounds *how many*: a grant on ``skynet/F/uav/*/state`` admits a subscriber on
``skynet/F/uav/x1/state``, ``.../x2/state``, ..., each a new resource in the router (about 2.6 KB,
``bench/declarations.py``). The router's admin space (``adminspace/enabled``) lists, per declared key
expression, the sessions that declare it (``@/<router>/router/{subscriber,queryable,token}/<key>``:
``{"clients": [zid, ...], "peers": [...]}``) and, per session link, the remote address and the certificate's
common name (``@/<router>/session/transport/unicast/<zid>/link/<id>``: ``{"dst", "auth_identifier"}``).

:class:`DeclarationCaps` sums the distinct key expressions each identity (common name) holds over all its
sessions; an identity above ``cap`` is banned for ``ban_s``: every session it holds, and every one it opens while
banned, is to be cut (the accept guard closes its TCP connections, :meth:`services.gateway.guard.Guard.cut`),
and each cut session is counted. What the admin space does not list is not counted: key expressions with a
verbatim ``@`` chunk (zenoh.ext's ``<key>/@adv/...``, which a UAV may declare under its own camera), and
repeats of one key by one session (about 40 bytes each at the router).
"""

from __future__ import annotations

import json
import logging
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from typing import NamedTuple

log = logging.getLogger("skynet.gateway.caps")

#: the kinds of declaration the router's admin space lists per key expression
KINDS = ("subscriber", "queryable", "token")
#: declarations one identity may hold at once over all its sessions (distinct key expressions); a UAV holds
#: about a dozen, the ground station a few dozen
DEFAULT_CAP = 1000
#: how long an identity over its cap stays banned (its sessions cut on sight), s
DEFAULT_BAN_S = 60.0


class Link(NamedTuple):
    """One link of a session as the router's admin space lists it."""

    zid: str
    identity: str  # the certificate's common name ("" without TLS)
    port: int | None  # the remote end's TCP port (the accept guard's relay socket behind a guard)


def selectors(router_zid: str) -> list[str]:
    """The admin-space selectors to query: every declaration kind, and every session link."""
    return [*(f"@/{router_zid}/router/{kind}/**" for kind in KINDS),
            f"@/{router_zid}/session/transport/unicast/*/link/*"]


def _port(locator: str) -> int | None:
    addr = locator.split("/", 1)[-1].split("?", 1)[0].split("#", 1)[0]
    try:
        return int(addr.rpartition(":")[2])
    except ValueError:
        return None


def parse(replies: Iterable[tuple[str, bytes]]) -> tuple[Counter[str], list[Link]]:
    """Declarations per session (distinct key expressions, by zid) and the sessions' links, from admin-space
    replies ``(key, payload)``; a reply that does not parse is skipped."""
    declared: Counter[str] = Counter()
    links: list[Link] = []
    seen: set[str] = set()
    for key, payload in replies:
        if key in seen:  # a key listed twice counts once
            continue
        seen.add(key)
        parts = key.split("/")
        try:
            body = json.loads(payload)
        except (ValueError, UnicodeDecodeError):
            continue
        if not isinstance(body, dict):
            continue
        if len(parts) > 3 and parts[2] == "router" and parts[3] in KINDS:
            for zid in [*(body.get("clients") or []), *(body.get("peers") or [])]:
                if isinstance(zid, str):
                    declared[zid] += 1
        elif len(parts) == 8 and parts[2:5] == ["session", "transport", "unicast"] and parts[6] == "link":
            ident = body.get("auth_identifier")
            dst = body.get("dst")
            links.append(Link(parts[5], ident if isinstance(ident, str) else "",
                              _port(dst) if isinstance(dst, str) else None))
    return declared, links


class DeclarationCaps:
    """The cap policy: which sessions to cut, given declarations per session and the sessions' links."""

    def __init__(self, cap: int = DEFAULT_CAP, ban_s: float = DEFAULT_BAN_S,
                 clock: Callable[[], float] = time.monotonic):
        self.cap, self.ban_s, self.clock = cap, ban_s, clock
        self.banned: dict[str, float] = {}  # identity -> until
        self.cut_sessions: Counter[str] = Counter()  # identity -> sessions cut
        self.peak: Counter[str] = Counter()  # identity -> most declarations held at once
        self._cut: set[str] = set()  # sessions (zids) already counted as cut

    def check(self, declared: Mapping[str, int], links: Iterable[Link]) -> list[Link]:
        """The links to cut: those of every session of an identity above the cap or banned."""
        now = self.clock()
        self.banned = {i: t for i, t in self.banned.items() if t > now}
        by_identity: dict[str, list[Link]] = {}
        zids: dict[str, set[str]] = {}
        for link in links:
            if link.identity:
                by_identity.setdefault(link.identity, []).append(link)
                zids.setdefault(link.identity, set()).add(link.zid)
        self._cut &= {link.zid for ls in by_identity.values() for link in ls}  # forget the sessions gone
        out: list[Link] = []
        for ident, ls in by_identity.items():
            total = sum(declared.get(z, 0) for z in zids[ident])
            self.peak[ident] = max(self.peak[ident], total)
            if total > self.cap and ident not in self.banned:
                self.banned[ident] = now + self.ban_s
                log.warning("%s holds %d declarations (cap %d): its sessions cut, banned for %g s",
                            ident, total, self.cap, self.ban_s)
            if ident in self.banned:
                self.cut_sessions[ident] += len(zids[ident] - self._cut)
                self._cut |= zids[ident]
                out += ls
        return out

    def counts(self) -> dict[str, int]:
        """Counters for the gateway's statistics: sessions cut per identity (``decl-cap-<identity>``)."""
        return {f"decl-cap-{i}": n for i, n in self.cut_sessions.items()}
