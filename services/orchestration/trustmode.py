"""How ``skynet up`` / ``skynet mission`` secure the network (issue 11): secure by default.

Default: a development key set (``--keys DIR``, else ``.keys/dev`` in the working folder, made by
:func:`services.keys.ensure` on first use and reused after), mutual TLS on every link with the
reliability classes kept on separate links (``tls/H:P?rel=1`` for commands, ``tls/H:Q?rel=0``
for telemetry and imagery: both are TCP underneath, see README "Trust"), access control by
certificate common name on the gateway and on each edge, commands and heartbeats signed by the
ground station and verified by the edges.

When a link is proxied (``--impair``, cut or partition faults) the user-space netem proxies model
the paper's UDP class, so the links stay plaintext TCP + UDP (no TLS, no certificate ACL) and
this says so; commands and heartbeats are still signed end to end. ``--insecure`` turns all of it
off, loudly; ``--secure`` is the older user/password mode (no TLS, no signatures).
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

#: where a development key set is kept between runs (git-ignored)
DEFAULT_KEYS = Path(".keys") / "dev"
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


def dev_keys(folder: str | Path, uavs: int) -> Path:
    """A development key set in ``folder`` covering ``uavs`` UAVs: reused, or made atomically (several
    launchers starting at once all end up with the same complete set)."""
    import shutil

    from services.keys import ensure, roles

    folder = Path(folder)

    def complete() -> bool:
        return (folder / "ca.pem").exists() and all((folder / r / "tls.pem").exists() for r in roles(uavs))

    if complete():
        return folder
    if (folder / "ca" / "ca.key").is_file():  # an older set lacking roles (UAVs, tools): issued by its own CA
        from services.keys import enlarge

        enlarge(folder, max(uavs, 3))
        if complete():
            return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".keys-", dir=folder.parent))
    ensure(tmp, max(uavs, 3))
    try:
        os.rename(tmp, folder)  # atomic; fails when the folder exists and is not empty
    except OSError:
        if not complete():  # an older, smaller set: put aside (rotation), install the new one
            os.rename(folder, folder.with_name(f"{folder.name}.old-{os.getpid()}"))
            os.rename(tmp, folder)
        else:  # another launcher won the race: use its set
            shutil.rmtree(tmp, ignore_errors=True)
    return folder


def resolve(args, proxied: bool) -> TrustPlan:
    """The trust plan of the launcher's options."""
    if getattr(args, "insecure", False) or getattr(args, "secure", False):
        warn = [INSECURE_BANNER] if getattr(args, "insecure", False) else [
            "--secure: user/password authentication and the gateway's ACL only (no TLS, unsigned commands)"]
        return TrustPlan(None, False, warn)
    keys = dev_keys(getattr(args, "keys", None) or DEFAULT_KEYS, args.uavs)
    plan = TrustPlan(keys.resolve(), not proxied)
    if proxied:
        plan.warnings.append("links proxied (impairment/faults): plaintext TCP/UDP links without TLS or "
                             "certificate ACL; commands and heartbeats still signed")
    return plan
