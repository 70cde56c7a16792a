"""How ``skynet up`` / ``skynet mission`` secure the network: secure by default, one model in every mode.

Design notes: docs/security.md (services/orchestration/trustmode.py).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .config import LaunchConfig

#: where a development key set is kept between runs (git-ignored)
DEFAULT_KEYS = Path(".keys") / "dev"
#: environment variable naming another folder for the development key set
KEYS_ENV = "SKYNET_KEYS"
INSECURE_BANNER = ("INSECURE (--insecure): no TLS, no access control, unsigned commands and heartbeats - "
                   "anyone who reaches these ports can command the UAVs")


@dataclass
class TrustPlan:
    keys: Path | None  # the key set of signed commands (None: unsigned)
    tls: bool  # mutual TLS links (and ACL by certificate common name)
    warnings: list[str] = field(default_factory=list)


def tls_endpoints(host: str, reliable_port: int, best_effort_port: int) -> list[str]:
    """The TLS multilink pair: each reliability class on its own mutually authenticated link."""
    return [f"tls/{host}:{reliable_port}?rel=1", f"tls/{host}:{best_effort_port}?rel=0"]


def gateway_dial(endpoint: str, keys: Path | None) -> str:
    """``endpoint`` of a gateway, dialled trusting the key set's router CA alone (Zenoh's per-endpoint TLS
    configuration, ``#root_ca_certificate_file=...``): a UAV, which trusts both CAs for the links it accepts,
    then reaches only a gateway certificate when it dials the gateway. Unchanged without TLS or a router CA."""
    router = None if keys is None else Path(keys) / "router-ca.pem"
    return dial_with_ca(endpoint, None if router is None or not router.is_file() else str(router.resolve()))


def dial_with_ca(endpoint: str, router_ca: str | None) -> str:
    """``endpoint`` with ``#root_ca_certificate_file=ROUTER_CA`` (a TLS endpoint only; pure: the file is not
    looked at). Unchanged without a CA, for a non-TLS endpoint, one that has its own configuration, or a path
    holding the endpoint syntax's characters (then the node's own CAs are used)."""
    if not endpoint.startswith("tls/") or "#" in endpoint or router_ca is None:
        return endpoint
    if any(c in router_ca for c in ";=#?"):
        return endpoint
    return f"{endpoint}#root_ca_certificate_file={router_ca}"


def default_keys() -> Path:
    """The development key set's folder: ``$SKYNET_KEYS`` when set (the test suite's own temporary set), else
    :data:`DEFAULT_KEYS`."""
    return Path(os.environ.get(KEYS_ENV) or DEFAULT_KEYS)


def dev_keys(folder: str | Path, uavs: int) -> Path:
    """A development key set in ``folder`` covering ``uavs`` UAVs: reused, or made under an exclusive lock on the
    parent folder (several launchers starting at once all end up with the same complete set; a smaller set is
    replaced in one rename and removed, leaving nothing behind)."""
    import fcntl
    import shutil

    from services.keys import ensure, usable

    folder = Path(folder)

    def complete() -> bool:
        return usable(folder, uavs)

    if complete():
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder.parent, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # a directory can be locked: no lock file left behind
        if complete():  # another launcher made it while this one waited
            return folder
        if (folder / "ca" / "ca.key").is_file() and (folder / "router-ca.pem").is_file():
            from services.keys import enlarge  # an older set lacking roles (UAVs, tools): issued by its own CA

            with contextlib.suppress(ValueError):  # not enlargeable: replaced below
                enlarge(folder, max(uavs, 3))
            if complete():
                return folder
        tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}-new-", dir=folder.parent))
        try:
            ensure(tmp, max(uavs, 3))
            if folder.exists():  # an older, smaller set: replaced (rotation)
                aside = Path(tempfile.mkdtemp(prefix=f".{folder.name}-old-", dir=folder.parent))
                os.rename(folder, aside / folder.name)
                os.rename(tmp, folder)
                shutil.rmtree(aside, ignore_errors=True)
            else:
                os.rename(tmp, folder)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    finally:
        os.close(fd)  # releases the lock
    return folder


def resolve(config: LaunchConfig, proxied: bool = False) -> TrustPlan:
    """The trust plan of the launcher's options: the same whether links are ``proxied`` or not."""
    if config.insecure:
        return TrustPlan(None, False, [INSECURE_BANNER])
    keys = dev_keys(config.keys or default_keys(), config.uavs)
    return TrustPlan(keys.resolve(), True, datagram_warnings(config.impair))


def datagram_warnings(impair: list[str]) -> list[str]:
    """What the secure mode makes of an impairment's datagram effects: the best-effort class rides a TLS stream
    (no UDP socket), where a lost segment is sent again, so loss is a retransmission delay and duplicates or
    reordering do not reach the receiver. One line per such ``--impair`` value."""
    from services.netem.model import parse_impair_arg

    out = []
    for text in impair:
        arg = parse_impair_arg(text)
        imp = arg.impairment
        if arg.cls != "tcp" and (imp.loss > 0 or imp.gilbert_elliott is not None or imp.duplicate > 0 or imp.reorder > 0):
            out.append(f"--impair {text!r}: in the secure mode the best-effort class rides a TLS stream, so its loss is "
                       "a retransmission delay and nothing is dropped, duplicated or reordered on arrival "
                       "(--insecure for the paper's UDP class with datagram loss)")
    return out


def planned_keys(config: LaunchConfig) -> Path | None:
    """The key set's folder a run would use, without making it (a dry run): None with ``--insecure``."""
    return None if config.insecure else Path(config.keys or default_keys()).resolve()
