"""A fleet key set on disk: where each node finds its TLS certificate, its signing key and whom it trusts.

Design notes: docs/security.md (protocol/keyset.py).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from .signing import ReplayStore, Signer, Verifier, load_public

log = logging.getLogger("skynet.keyset")

_ROLE = re.compile(r"^(gateway|gcs|planner|detector|video|web|replay|uav([1-9][0-9]{0,2}))$")
_KID = re.compile(r"^[0-9a-f]{16}$")
#: a certificate's common name: the role, then ``.gN`` from its second issue on
_CN = re.compile(r"^([a-z]+[0-9]*)(?:\.g([1-9][0-9]{0,5}))?$")


def role_of_cn(cn: str) -> str:
    """The role a node certificate's common name speaks for (``uav2.g3`` -> ``uav2``); ValueError otherwise."""
    m = _CN.match(cn or "")
    if not m:
        raise ValueError(f"not a node certificate name: {cn!r}")
    return check_role(m.group(1))


def check_role(role: str) -> str:
    m = _ROLE.match(role or "")
    if not m or (m.group(2) and int(m.group(2)) > 255):
        raise ValueError(f"role must be gateway, gcs, planner, detector, video, web, replay or uav1..uav255, got {role!r}")
    return role


@dataclass(frozen=True)
class KeySet:
    """One node's view of a key set folder."""

    root: Path
    role: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root))
        check_role(self.role)
        if not self.ca.is_file():
            raise ValueError(f"{self.root}: not a key set (no ca.pem; make one with `skynet keys init {self.root}`)")

    @property
    def ca(self) -> Path:
        return self.root / "ca.pem"

    @property
    def tls_ca(self) -> Path:
        """The trust anchors of this node's TLS links. A node that only dials the gateway (every role but the
        gateway and the UAVs) trusts the router CA alone, so whatever answers its dial must hold a gateway
        certificate: a stolen node certificate cannot pose as its router. The gateway and the UAVs accept links
        from both kinds and trust both CAs; what an impostor says there is bound by the ACL of its own common name."""
        router = self.root / "router-ca.pem"
        if self.role == "gateway" or self.role.startswith("uav") or not router.is_file():
            return self.ca
        return router

    @property
    def node(self) -> Path:
        return self.root / self.role

    @property
    def tls_cert(self) -> Path:
        return self.node / "tls.pem"

    @property
    def tls_key(self) -> Path:
        return self.node / "tls.key"

    @property
    def replay_file(self) -> Path:
        """Where this node keeps its replay window (next to its keys: survives a restart)."""
        return self.node / "replay.json"

    def uavs(self) -> list[int]:
        """The UAV ids with a folder in this key set."""
        return sorted(int(p.name[3:]) for p in self.root.glob("uav*") if p.is_dir() and p.name[3:].isdigit())

    def signer(self) -> Signer:
        return Signer.from_file(self.role, self.node / "sign.key")

    def trusted(self) -> dict[str, list[Ed25519PublicKey]]:
        """Trusted signers: ``trust/<signer>.pub`` and ``trust/<signer>.<anything>.pub`` (rotation overlap)."""
        out: dict[str, list[Ed25519PublicKey]] = {}
        for path in sorted((self.root / "trust").glob("*.pub")):
            out.setdefault(path.name.split(".")[0], []).append(load_public(path))
        return out

    def _revocations(self) -> tuple[set[str], set[str]]:
        """(revoked key ids, revoked certificate common names) of ``revoked.txt``."""
        path = self.root / "revoked.txt"
        kids: set[str] = set()
        names: set[str] = set()
        if not path.exists():
            return kids, names
        for n, raw in enumerate(path.read_text().splitlines(), start=1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            kind, _, name = line.partition(" ")
            if kind == "cert" and name.strip():
                try:
                    role_of_cn(name.strip())
                except ValueError as exc:
                    raise ValueError(f"{path} line {n}: {exc}") from None
                names.add(name.strip())
            elif _KID.match(line):
                kids.add(line)
            else:
                raise ValueError(f"{path} line {n}: expected a 16-hex-digit key id or 'cert NAME', got {line!r}")
        return kids, names

    def revoked(self) -> set[str]:
        """Revoked signing key ids."""
        return self._revocations()[0]

    def revoked_certs(self) -> set[str]:
        """Common names of revoked certificates."""
        return self._revocations()[1]

    def admitted(self) -> list[str]:
        """The certificate common names the access control admits: ``certs.txt`` (else, in an older key set,
        every node folder's role), less the revoked ones."""
        path = self.root / "certs.txt"
        if path.exists():
            names = []
            for n, raw in enumerate(path.read_text().splitlines(), start=1):
                line = raw.split("#", 1)[0].strip()
                if line:
                    try:
                        role_of_cn(line)
                    except ValueError as exc:
                        raise ValueError(f"{path} line {n}: {exc}") from None
                    names.append(line)
        else:
            names = sorted(p.name for p in self.root.iterdir() if (p / "tls.pem").is_file() and _ROLE.match(p.name))
        gone = self.revoked_certs()
        return [n for n in names if n not in gone]

    def verifier(self, stale_s: float | None = None, persist: bool = True,
                 replay_file: str | Path | None = None) -> Verifier:
        """A verifier of the trusted signers, with this node's persisted replay window (in
        ``replay_file`` when given: a key set mounted read-only, e.g. docker compose's)."""
        kw: dict[str, Any] = {} if stale_s is None else {"stale_s": stale_s}
        path = (replay_file or self.replay_file) if persist else None
        return Verifier(self.trusted(), self.revoked(), ReplayStore(path), **kw)


class RevocationWatch:
    """The revoked signing key ids of a key set's ``revoked.txt``, read again when the file changes, so that
    ``skynet keys revoke`` beside a running node takes effect there at once (docs/security.md)."""

    def __init__(self, keyset: KeySet, min_interval_s: float = 1.0, clock: Callable[[], float] = time.monotonic):
        self.path = keyset.root / "revoked.txt"
        self._keyset, self._interval, self._clock = keyset, float(min_interval_s), clock
        self._stamp = self._stat()
        self._checked = clock()
        self._unreadable = False

    def _stat(self) -> tuple[int, int, int] | None:
        try:
            st = self.path.stat()
        except OSError:
            return None
        return st.st_mtime_ns, st.st_size, st.st_ino

    def __call__(self) -> frozenset[str] | None:
        """The revoked key ids when ``revoked.txt`` changed since they were last returned; None when it did not,
        when it was looked at less than ``min_interval_s`` ago, or while it does not parse (the last good set
        stays, and the file is read again at the next look)."""
        now = self._clock()
        if now - self._checked < self._interval:
            return None
        self._checked = now
        stamp = self._stat()
        if stamp == self._stamp:
            return None
        try:
            kids = frozenset(self._keyset.revoked())
        except (OSError, ValueError) as exc:
            if not self._unreadable:
                log.warning("revocations unreadable (%s): the revoked keys stay as they were", exc)
            self._unreadable = True
            return None
        self._stamp, self._unreadable = stamp, False
        return kids


class AdmissionWatch:
    """The certificate common names a running node admits, read again as the key set changes beside it
    (``skynet keys revoke|reissue``), so that the node can reopen its session with the new access control.

    A change is taken once two reads ``min_interval_s`` apart agree on it (a key set being rewritten may be
    read between its files' writes); a key set that does not read is logged once and the names stay."""

    def __init__(self, read: Callable[[], list[str]], current: list[str], min_interval_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic):
        self._read, self.current, self._interval, self._clock = read, sorted(current), float(min_interval_s), clock
        self._checked = clock()
        self._pending: list[str] | None = None
        self.unreadable = False

    def __call__(self) -> list[str] | None:
        """The admitted names when a change was just taken (``current`` is then those), else None."""
        now = self._clock()
        if now - self._checked < self._interval:
            return None
        self._checked = now
        try:
            names = sorted(self._read())  # the order of certs.txt's lines is not a change
        except (OSError, ValueError) as exc:
            if not self.unreadable:
                log.warning("key set unreadable (%s): the ACL stays as it is", exc)
            self.unreadable = True
            return None
        self.unreadable = False
        if names == self.current:
            self._pending = None
        elif names != self._pending:
            self._pending = names
        else:
            self._pending, self.current = None, names
            return names
        return None
