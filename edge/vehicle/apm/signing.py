"""MAVLink 2 message signing (https://mavlink.io/en/guide/message_signing.html) done in the safe order.

Design notes: docs/hardware-mavlink.md (edge/vehicle/apm/signing.py).
"""

from __future__ import annotations

import hashlib
import hmac
import re
import time

from pymavlink.dialects.v20 import ardupilotmega as M

__all__ = ["parse_key", "SafeSigningMAVLink", "enable_signing", "signing_timestamp"]

#: seconds from the UNIX epoch to 2015-01-01T00:00:00Z, the signing epoch
_EPOCH_2015 = 1420070400


def parse_key(text: str) -> bytes:
    """A 32-byte signing key: 64 hex digits as they are, anything else is a passphrase hashed with SHA-256."""
    if not isinstance(text, str) or not text:
        raise ValueError("the MAVLink signing key must be a non-empty string (64 hex digits or a passphrase)")
    t = text.strip()
    if re.fullmatch(r"[0-9a-fA-F]{64}", t):
        return bytes.fromhex(t)
    return hashlib.sha256(t.encode()).digest()


def signing_timestamp(now: float | None = None) -> int:
    """The signing timestamp for UNIX time ``now`` (10 µs units since 2015)."""
    t = time.time() if now is None else now
    return int((t - _EPOCH_2015) * 100_000)


class SafeSigningMAVLink(M.MAVLink):
    """pymavlink's MAVLink 2 codec with the signature verified before the stream timestamp is recorded."""

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:  # noqa: N803
        s = self.signing
        assert s.secret_key is not None
        sig = hashlib.sha256(s.secret_key + bytes(msgbuf[:-6])).digest()[:6]
        if not hmac.compare_digest(sig, bytes(msgbuf[-6:])):
            return False  # forged or corrupted: the stream's timestamp is left alone
        tlow, thigh = self.mav_sign_unpacker.unpack(msgbuf[-12:-6])
        timestamp = tlow + (thigh << 32)
        key = (msgbuf[-13], srcSystem, srcComponent)
        last = s.stream_timestamps.get(key)
        if last is not None:
            if timestamp <= last:
                return False  # a replay
        elif timestamp + 6_000_000 < s.timestamp:
            return False  # a new stream more than a minute behind our clock
        s.stream_timestamps[key] = timestamp
        s.timestamp = max(s.timestamp, timestamp)
        return True


def _allow_radio_status(mav: M.MAVLink, msg_id: int) -> bool:
    return msg_id == M.MAVLINK_MSG_ID_RADIO_STATUS


def enable_signing(conn: object, key: bytes, link_id: int = 0, allow_unsigned: bool = False) -> None:
    """Sign every outgoing packet of a pymavlink connection and accept only correctly signed ones.

    ``conn.mav`` must be a :class:`SafeSigningMAVLink` (see :func:`edge.vehicle.mavlink.open_connection`).
    """
    mav = conn.mav  # type: ignore[attr-defined]
    if not isinstance(mav, SafeSigningMAVLink):
        raise ValueError("the connection's codec must be a SafeSigningMAVLink")
    if not (isinstance(key, bytes) and len(key) == 32):
        raise ValueError("the signing key must be 32 bytes")
    if not (isinstance(link_id, int) and 0 <= link_id <= 255):
        raise ValueError("link_id must be an int in 0..255")
    s = mav.signing
    s.secret_key = key
    s.link_id = link_id
    s.timestamp = max(s.timestamp, signing_timestamp())
    s.sign_outgoing = True
    s.allow_unsigned_callback = (lambda m, i: True) if allow_unsigned else _allow_radio_status
