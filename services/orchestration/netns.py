"""Network namespaces as stand-in hosts on one machine: one per site, veth pairs between them.

Design notes: docs/experiments.md (services/orchestration/netns.py).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import uuid

from .sites import Mesh, veth_addresses

__all__ = ["available", "Namespaces"]


def _ip(*args: str, ns: str | None = None) -> subprocess.CompletedProcess:
    cmd = ["ip", *(["-n", ns] if ns else []), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=10)


def available() -> tuple[bool, str]:
    """Whether namespaces can be made here, and why not."""
    if shutil.which("ip") is None:
        return False, "iproute2's ip is not installed"
    if os.geteuid() != 0:
        return False, "network namespaces need root (CAP_NET_ADMIN)"
    probe = f"skynet-probe-{uuid.uuid4().hex[:6]}"
    r = _ip("netns", "add", probe)
    if r.returncode != 0:
        return False, f"ip netns add failed: {r.stderr.strip()}"
    _ip("netns", "del", probe)
    return True, ""


class Namespaces:
    """The namespaces and veth links of a mesh; a context manager that removes them on exit."""

    def __init__(self, mesh: Mesh, tag: str | None = None):
        self.mesh = mesh
        self.tag = tag or uuid.uuid4().hex[:6]
        self.names = [f"skynet-{self.tag}-s{s.index}" for s in mesh.sites]
        self.addresses = veth_addresses(mesh.links)
        self._made: list[str] = []

    def prefix(self, site: int) -> list[str]:
        """The command prefix that runs a process in site ``site``'s namespace."""
        return ["ip", "netns", "exec", self.names[site]]

    def address(self, site: int, peer: int) -> str:
        """Site ``site``'s interface address (``a.b.c.d/30``) on its router link with ``peer``."""
        i, j = sorted((site, peer))
        a, b = self.addresses[(i, j)]
        return a if site == i else b

    def _check(self, r: subprocess.CompletedProcess, what: str) -> None:
        if r.returncode != 0:
            raise RuntimeError(f"{what}: {r.stderr.strip() or r.stdout.strip()}")

    def open(self) -> Namespaces:
        try:
            for name in self.names:
                self._check(_ip("netns", "add", name), f"ip netns add {name}")
                self._made.append(name)
                self._check(_ip("link", "set", "lo", "up", ns=name), f"lo up in {name}")
            for p, (i, j) in enumerate(self.mesh.links):
                a, b = f"sk{self.tag}{p}a", f"sk{self.tag}{p}b"  # at most 15 characters
                ni, nj = self.names[i], self.names[j]
                # made inside namespace i, its peer end moved to namespace j: the machine's own is never touched
                self._check(_ip("link", "add", a, "type", "veth", "peer", "name", b, "netns", nj, ns=ni),
                            f"veth {a}/{b}")
                for ns, dev, addr in ((ni, a, self.address(i, j)), (nj, b, self.address(j, i))):
                    self._check(_ip("addr", "add", addr, "dev", dev, ns=ns), f"address {addr} on {dev}")
                    self._check(_ip("link", "set", dev, "up", ns=ns), f"{dev} up")
        except Exception:
            self.close()
            raise
        return self

    def close(self) -> None:
        for name in reversed(self._made):
            _ip("netns", "del", name)
        self._made.clear()

    def __enter__(self) -> Namespaces:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
