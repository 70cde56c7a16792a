"""MAVLink 2 signing: the signature is checked before the stream timestamp (the lock-out attack).

pymavlink's own codec records a signed packet's timestamp before checking its signature, so one
forged packet with a future timestamp makes every genuine packet after it look like a replay.
The test shows the attack on the stock codec and that SafeSigningMAVLink is immune to it.
"""

from __future__ import annotations

import struct
import types

import pytest

pytest.importorskip("pymavlink", reason="signing needs the 'mavlink' extra")

from pymavlink.dialects.v20 import ardupilotmega as M  # noqa: E402

from edge.vehicle.apm.signing import SafeSigningMAVLink, enable_signing, parse_key, signing_timestamp  # noqa: E402

KEY = parse_key("correct horse battery staple")


def signer() -> M.MAVLink:
    mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.signing.secret_key = KEY
    mav.signing.sign_outgoing = True
    mav.signing.timestamp = signing_timestamp()
    return mav


def heartbeat(mav: M.MAVLink) -> bytes:
    return bytes(mav.heartbeat_encode(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0).pack(mav))


def forged_future(genuine: bytes, years: float = 1.0) -> bytes:
    """The genuine packet with its timestamp moved a year ahead; the signature (unknown key) left as it was."""
    b = bytearray(genuine)
    ts = int.from_bytes(b[-12:-6], "little") + int(years * 365 * 86400 * 100_000)
    b[-12:-6] = (ts & 0xFFFFFFFFFFFF).to_bytes(6, "little")
    return bytes(b)  # the CRC covers header and payload only, so the frame still parses


def receiver(cls) -> M.MAVLink:
    mav = cls(None)
    mav.robust_parsing = True
    mav.signing.secret_key = KEY
    mav.signing.timestamp = signing_timestamp()
    return mav


def accepted(mav: M.MAVLink, packet: bytes) -> bool:
    good = mav.signing.goodsig_count
    mav.parse_buffer(packet)
    return mav.signing.goodsig_count > good


def test_the_stock_codec_is_locked_out_by_one_forged_packet_and_the_safe_one_is_not():
    tx = signer()
    first, second = heartbeat(tx), heartbeat(tx)
    stock = receiver(M.MAVLink)
    assert accepted(stock, first)
    assert not accepted(stock, forged_future(first))
    assert not accepted(stock, second), "the attack no longer works on pymavlink: this guard may be dropped"

    tx = signer()
    first, second, third = heartbeat(tx), heartbeat(tx), heartbeat(tx)
    safe = receiver(SafeSigningMAVLink)
    assert accepted(safe, first)
    assert not accepted(safe, forged_future(first))
    assert accepted(safe, second) and accepted(safe, third)
    assert safe.signing.badsig_count == 1


def test_replays_and_wrong_keys_are_still_refused():
    tx = signer()
    a, b = heartbeat(tx), heartbeat(tx)
    safe = receiver(SafeSigningMAVLink)
    assert accepted(safe, b)
    assert not accepted(safe, b)  # the same packet again
    assert not accepted(safe, a)  # an older one
    other = signer()
    other.signing.secret_key = parse_key("another key")
    assert not accepted(safe, heartbeat(other))


def test_unsigned_packets_are_refused_except_radio_status():
    safe = SafeSigningMAVLink(None)
    safe.robust_parsing = True
    enable_signing(types.SimpleNamespace(mav=safe), KEY)
    plain = M.MAVLink(None, srcSystem=1, srcComponent=1)
    msgs = safe.parse_buffer(heartbeat(plain)) or []
    assert [m.get_type() for m in msgs] in ([], ["BAD_DATA"])
    radio = bytes(plain.radio_status_encode(200, 200, 50, 10, 10, 0, 0).pack(plain))
    assert [m.get_type() for m in safe.parse_buffer(radio) or []] == ["RADIO_STATUS"]


def test_keys():
    hexkey = "00" * 31 + "ff"
    assert parse_key(hexkey) == bytes(31) + b"\xff"
    assert len(parse_key("a passphrase")) == 32
    with pytest.raises(ValueError):
        parse_key("")
    with pytest.raises(ValueError):
        enable_signing(types.SimpleNamespace(mav=M.MAVLink(None)), KEY)  # the stock codec is refused
    with pytest.raises(ValueError):
        enable_signing(types.SimpleNamespace(mav=SafeSigningMAVLink(None)), b"short")
    assert struct.calcsize("<IH") == 6  # the 48-bit timestamp layout pymavlink unpacks
