"""The board's gatekeeper: signed commands and heartbeats checked before anything else, bodies bound to keys.

Design notes: docs/security.md (edge/trust.py).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from protocol import keys
from protocol.messages import COMMAND_TYPES, Heartbeat, Message, Signed
from protocol.signing import Refusal, TrustError, Verifier, unverified_inner

if TYPE_CHECKING:
    from protocol.keyset import KeySet

    from .config import EdgeConfig

log = logging.getLogger("skynet.edge.trust")

#: at most one event per refusal reason per this many seconds
EVENT_PERIOD_S = 1.0


class Gate:
    """Trust checks of one UAV's board; ``verifier=None`` is the insecure mode."""

    def __init__(self, fleet: str, uav: int, verifier: Verifier | None, clock=time.monotonic,
                 revocations: Callable[[], frozenset[str] | None] | None = None):
        self.fleet, self.uav, self.verifier = fleet, uav, verifier
        #: the revoked key ids when they changed, else None (:class:`protocol.keyset.RevocationWatch`)
        self._revocations = revocations
        self.cmd_key = keys.cmd(fleet, uav)
        self.heartbeat_key = keys.heartbeat(fleet)
        self.refused: collections.Counter[str] = collections.Counter()
        self._reported: dict[str, tuple[float, int]] = {}  # reason -> (last event time, count then)
        self._clock = clock
        self._lock = threading.Lock()

    def _count(self, what: str) -> None:
        with self._lock:
            self.refused[what] += 1

    def _refresh(self) -> None:
        if self.verifier is None or self._revocations is None:
            return
        kids = self._revocations()
        if kids is not None and kids != self.verifier.revoked:
            log.warning("uav%d: revoked signing keys now %s", self.uav, ", ".join(sorted(kids)) or "none")
            self.verifier.revoked = kids

    def command(self, msg: Message) -> Message:
        """The command to act on; raises :class:`TrustError` (counted) when it must be refused."""
        self._refresh()
        try:
            if self.verifier is None:
                if isinstance(msg, Signed):
                    raise TrustError(Refusal.UNKNOWN_SIGNER, "signed command but this board has no trusted keys")
                return msg
            return self.verifier.verify(msg, self.cmd_key, COMMAND_TYPES).message
        except TrustError as exc:
            self._count(f"command.{exc.reason.value}")
            raise

    def heartbeat(self, msg: Message) -> TrustError | None:
        """None when ``msg`` is a heartbeat that may reset the failsafe timer, else why not (counted)."""
        if self.verifier is None:
            return None if isinstance(msg, Heartbeat) else TrustError(Refusal.UNKNOWN_SIGNER, "no trusted keys")
        self._refresh()
        try:
            self.verifier.verify(msg, self.heartbeat_key, Heartbeat)
            return None
        except TrustError as exc:
            self._count(f"heartbeat.{exc.reason.value}")
            return exc

    def body_matches(self, uav: int, msg: Message) -> bool:
        """Whether the ``uav`` of ``msg`` is ``uav``, the UAV whose key it came on (the board subscribes once
        per neighbour, so the key is known without parsing it; :mod:`protocol.binding` for the rule);
        counted as ``body.mismatch`` if not."""
        ok = getattr(msg, "uav", -1) == uav
        if not ok:
            self._count("body.mismatch")
        return ok

    def report(self, what: str) -> int:
        """How many refusals of ``what`` to report now (0: stay quiet, an event went out recently)."""
        now = self._clock()
        with self._lock:
            total = self.refused[what]
            last = self._reported.get(what)
            if last is not None and now - last[0] < EVENT_PERIOD_S:
                return 0
            self._reported[what] = (now, total)
            return total - (last[1] if last else 0)

    def counters(self) -> dict[str, Any]:
        with self._lock:
            return dict(self.refused)


def command_id(msg: Message) -> int:
    """The ``cmd_id`` to acknowledge a refused message with (unverified: only for the sender's bookkeeping)."""
    cmd_id = getattr(msg, "cmd_id", None)
    if isinstance(cmd_id, int):
        return cmd_id
    if isinstance(msg, Signed):
        try:
            inner = unverified_inner(msg)
        except ValueError:  # a refused envelope may hold anything: bad base64, bad bytes (CodecError)
            return 0
        cmd_id = getattr(inner, "cmd_id", None)
        return cmd_id if isinstance(inner, COMMAND_TYPES) and isinstance(cmd_id, int) else 0
    return 0


class Admission:
    """Which node certificates an edge's own sessions admit (its SkyNet peers and the gateway), read from the key
    set at the start and again, by :attr:`watch` (:class:`protocol.keyset.AdmissionWatch`), as it changes."""

    def __init__(self, keyset: KeySet, fleet: str, mesh: set[str]):
        from protocol.keyset import AdmissionWatch

        self.keyset, self.fleet, self.mesh = keyset, fleet, frozenset(mesh)
        self.watch = AdmissionWatch(self.peers, self.peers())

    def peers(self) -> list[str]:
        """The admitted common names of the mesh's roles (``certs.txt``; a key set without it, older or a
        vehicle's, admits the roles less the revoked ones)."""
        from protocol.keyset import role_of_cn

        ks = self.keyset
        names = ks.admitted() if (ks.root / "certs.txt").exists() else sorted(self.mesh - ks.revoked_certs())
        return [cn for cn in names if role_of_cn(cn) in self.mesh]

    def access_control(self) -> dict:
        """Zenoh's ACL admitting the names admitted now (:func:`protocol.acl.cert_access_control`)."""
        from protocol.acl import cert_access_control

        return cert_access_control(self.fleet, self.watch.current)


def secure_setup(config: EdgeConfig, log=None) -> tuple[Gate, Admission | None]:
    """The edge's gate and certificate admission from its options: ``--keys DIR`` (verifier with the persisted
    replay window of ``DIR/uavN/replay.json``, ACL by certificate common name), or ``--insecure``.

    Without either the board runs insecure and says so loudly (``skynet up``/``mission`` always
    give one or the other).
    """
    if not config.keys or config.insecure:
        if log:
            log.warning("INSECURE: uav%d obeys unsigned commands and heartbeats from anyone on the bus%s",
                        config.uav, "" if config.insecure else " (no --keys given)")
        return Gate(config.fleet, config.uav, None), None
    from protocol.keyset import KeySet, RevocationWatch

    ks = KeySet(config.keys, f"uav{config.uav}")
    watch = RevocationWatch(ks)  # before the verifier reads revoked.txt, so that no change falls between them
    verifier = ks.verifier(stale_s=config.trust_window, replay_file=config.replay_state)
    n = config.mesh_uavs or max([config.uav, *ks.uavs()])
    admission = Admission(ks, config.fleet, {"gateway", *(f"uav{i}" for i in range(1, n + 1))})
    endpoints = [*config.listen, *config.connect]
    plain = [e for e in endpoints if not e.startswith("tls/")]
    if log:
        log.info("trust: commands signed by %s, replay window %s", ", ".join(ks.trusted()) or "nobody",
                 verifier.replay.path)
        if plain:
            log.warning("links without TLS (%s): no certificate there, so denied everything", ", ".join(plain))
    return Gate(config.fleet, config.uav, verifier, revocations=watch), admission
