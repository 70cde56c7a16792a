"""End-to-end signed messages: Ed25519 envelopes for commands and ground-station heartbeats.

Design notes: docs/security.md (protocol/signing.py).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import math
import os
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import msgpack
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from . import codec
from .messages import Message, Signed

#: domain separation: a signature made for this protocol cannot be taken for another's
DOMAIN = "skynet-signed-v1"
#: messages whose stamp is further than this from the verifier's clock are stale, s
DEFAULT_STALE_S = 10.0


class Refusal(str, Enum):
    """Why a signed message was refused (the acknowledgement's reason starts with it)."""

    UNSIGNED = "unsigned"
    UNKNOWN_SIGNER = "unknown-signer"
    REVOKED = "revoked"
    BAD_SIGNATURE = "bad-signature"
    WRONG_ADDRESSEE = "wrong-addressee"
    STALE = "stale"
    REPLAYED = "replayed"
    MALFORMED = "malformed"


class TrustError(ValueError):
    """A refused message: ``reason`` is the :class:`Refusal`, ``detail`` says more."""

    def __init__(self, reason: Refusal, detail: str):
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason
        self.detail = detail


# ----------------------------------------------------------------------------- keys
def key_id(public: Ed25519PublicKey) -> str:
    """The key's id: the first 16 hex digits of SHA-256 over its 32 raw bytes."""
    raw = public.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()[:16]


def load_private(path: str | Path) -> Ed25519PrivateKey:
    key = serialization.load_pem_private_key(Path(path).read_bytes(), password=None)
    if not isinstance(key, Ed25519PrivateKey):
        raise ValueError(f"{path}: not an Ed25519 private key")
    return key


def load_public(path: str | Path) -> Ed25519PublicKey:
    key = serialization.load_pem_public_key(Path(path).read_bytes())
    if not isinstance(key, Ed25519PublicKey):
        raise ValueError(f"{path}: not an Ed25519 public key")
    return key


def signed_bytes(signer: str, kid: str, seq: int, stamp: float, to: str, type_: str, body: bytes) -> bytes:
    """The canonical bytes a signature covers."""
    out: bytes = msgpack.packb([DOMAIN, signer, kid, seq, float(stamp), to, type_, body], use_bin_type=True)
    return out


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def _unb64(text: str, what: str) -> bytes:
    try:
        return base64.b64decode(text.encode("ascii"), validate=True)
    except (binascii.Error, ValueError, UnicodeEncodeError):
        raise TrustError(Refusal.MALFORMED, f"{what} is not base64") from None


# ----------------------------------------------------------------------------- signing
class Signer:
    """Signs messages as ``name`` with one Ed25519 private key; thread-safe."""

    def __init__(self, name: str, private: Ed25519PrivateKey, clock: Callable[[], float] = time.time):
        self.name = name
        self._key = private
        self.kid = key_id(private.public_key())
        self._clock = clock
        self._last = 0
        self._lock = threading.Lock()

    @classmethod
    def from_file(cls, name: str, path: str | Path) -> Signer:
        return cls(name, load_private(path))

    def next_seq(self) -> int:
        with self._lock:
            self._last = max(self._last + 1, int(self._clock() * 1e6))
            return self._last

    def sign(self, msg: Message, to: str) -> Signed:
        """``msg`` in a signed envelope addressed to the key expression ``to``."""
        body = codec.encode(msg)
        seq, stamp = self.next_seq(), float(self._clock())
        sig = self._key.sign(signed_bytes(self.name, self.kid, seq, stamp, to, msg.TYPE, body))
        return Signed(signer=self.name, kid=self.kid, seq=seq, stamp=stamp, to=to, type=msg.TYPE,
                      body=_b64(body), sig=_b64(sig))


def unverified_inner(msg: Message) -> Message:
    """The message inside a :class:`Signed` envelope, decoded but NOT verified (for logs and their
    readers, never for acting on it); any other message is returned as it is."""
    if not isinstance(msg, Signed):
        return msg
    return codec.decode(_unb64(msg.body, "body"))


# ----------------------------------------------------------------------------- replay window
class ReplayStore:
    """The last accepted sequence per stream (``signer|addressee``), optionally persisted.

    ``path=None`` keeps it in memory only. The file is rewritten atomically (write, fsync, rename)
    on every acceptance; a missing file starts empty, an unreadable one raises ValueError (an edge
    must not silently forget what it accepted).
    """

    def __init__(self, path: str | Path | None = None):
        self.path = Path(path) if path is not None else None
        self._last: dict[str, int] = {}
        self._lock = threading.Lock()
        if self.path is not None and self.path.exists():
            try:
                data = json.loads(self.path.read_text())
                if not isinstance(data, dict) or not all(isinstance(v, int) for v in data.values()):
                    raise ValueError("not a map of sequence numbers")
            except (ValueError, OSError) as exc:
                raise ValueError(f"replay state {self.path} unreadable: {exc}") from None
            self._last = {str(k): int(v) for k, v in data.items()}

    def last(self, stream: str) -> int | None:
        with self._lock:
            return self._last.get(stream)

    def accept(self, stream: str, seq: int) -> bool:
        """Record ``seq`` if it is above the last accepted one for ``stream``; False if not."""
        with self._lock:
            last = self._last.get(stream)
            if last is not None and seq <= last:
                return False
            self._last[stream] = seq
            if self.path is not None:
                # a name of its own: two edges sharing a key folder (parallel dev runs) never collide
                tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}.tmp")
                with open(tmp, "w") as f:
                    json.dump(self._last, f)
                    f.flush()
                    os.fsync(f.fileno())
                os.replace(tmp, self.path)
            return True


# ----------------------------------------------------------------------------- verifying
@dataclass(frozen=True)
class Verified:
    message: Message
    signer: str
    seq: int
    stamp: float


class Verifier:
    """Verifies :class:`Signed` envelopes against the ``trusted`` Ed25519 keys per signer (an edge trusts the
    ground station's only), the ``revoked`` key ids, a per-stream ``replay`` store (persisted on an edge)
    and a clock distance of at most ``stale_s``."""

    def __init__(self, trusted: Mapping[str, Iterable[Ed25519PublicKey]], revoked: Iterable[str] = (),
                 replay: ReplayStore | None = None, stale_s: float = DEFAULT_STALE_S,
                 clock: Callable[[], float] = time.time):
        if not (stale_s > 0 and math.isfinite(stale_s)):
            raise ValueError("stale_s must be a positive number of seconds")
        self._keys: dict[tuple[str, str], Ed25519PublicKey] = {}
        for name, pubs in trusted.items():
            for pub in pubs:
                self._keys[(name, key_id(pub))] = pub
        self.revoked = frozenset(revoked)
        self.replay = replay or ReplayStore()
        self.stale_s = float(stale_s)
        self._clock = clock

    def verify(self, msg: Message, to: str, expect: type[Message] | tuple[type[Message], ...] | None = None
               ) -> Verified:
        """The verified inner message of ``msg`` sent on ``to``; raises :class:`TrustError`."""
        if not isinstance(msg, Signed):
            raise TrustError(Refusal.UNSIGNED, f"{getattr(msg, 'TYPE', type(msg).__name__)} without a signature")
        pub = self._keys.get((msg.signer, msg.kid))
        if msg.kid in self.revoked:
            raise TrustError(Refusal.REVOKED, f"key {msg.kid} of {msg.signer!r} is revoked")
        if pub is None:
            raise TrustError(Refusal.UNKNOWN_SIGNER, f"no trusted key {msg.kid} for signer {msg.signer!r}")
        body, sig = _unb64(msg.body, "body"), _unb64(msg.sig, "signature")
        try:
            pub.verify(sig, signed_bytes(msg.signer, msg.kid, msg.seq, msg.stamp, msg.to, msg.type, body))
        except InvalidSignature:
            raise TrustError(Refusal.BAD_SIGNATURE, f"signature of {msg.signer!r} does not verify") from None
        if msg.to != to:
            raise TrustError(Refusal.WRONG_ADDRESSEE, f"signed for {msg.to!r}, received on {to!r}")
        age = self._clock() - msg.stamp
        if abs(age) > self.stale_s:
            raise TrustError(Refusal.STALE, f"stamp {age:+.1f} s from now (window ±{self.stale_s:g} s)")
        try:
            inner = codec.decode(body, expect)
        except codec.CodecError as exc:
            raise TrustError(Refusal.MALFORMED, f"body: {exc}") from None
        if inner.TYPE != msg.type:
            raise TrustError(Refusal.MALFORMED, f"envelope says {msg.type!r}, body is {inner.TYPE!r}")
        stream = f"{msg.signer}|{to}"
        if not self.replay.accept(stream, msg.seq):
            raise TrustError(Refusal.REPLAYED, f"sequence {msg.seq} not above the last accepted "
                                               f"{self.replay.last(stream)} from {msg.signer!r}")
        return Verified(inner, msg.signer, msg.seq, msg.stamp)
