"""Bodies bound to keys: a message may speak only for the node whose key it travels on.

Design notes: docs/security.md (protocol/binding.py).
"""

from __future__ import annotations

from . import keys
from .rtp import parse_ssrc

#: the rejection kind counted per key
MISMATCH = "body-mismatch"


def source_of(key: str) -> str | None:
    """The only ``source`` a body on ``key`` may claim; None when ``key`` is not a key of the key space."""
    try:
        info = keys.parse(key)
    except keys.KeyError_:
        return None
    if info.area == "uav":
        return f"uav/{info.uav}"
    if info.area == "gcs":
        return "gcs"
    if info.area == "rcu":
        return info.name
    if info.area == "gateway":
        return f"gateway/{info.name}"
    return None


def source_matches(key: str, source: str | None) -> bool:
    """Whether a body's claimed ``source`` is the one of ``key`` (:func:`source_of`); any source, any role."""
    expected = source_of(key)
    return expected is not None and source == expected


def matches(key: str, uav: int | None, source: str | None = None) -> bool:
    """Whether ``uav`` (a body's ``uav`` field) is the UAV of ``key``, or, without ``uav``, whether
    ``source`` (an event's or statistics' ``source``) is the source of ``key`` (:func:`source_matches`).

    Keys outside the UAV area (ground station, RCUs, gateways) carry no UAV id: a body there that
    names a UAV does not match.
    """
    try:
        info = keys.parse(key)
    except keys.KeyError_:
        return False
    if uav is not None:
        return info.uav == uav
    if source is not None:
        return source_matches(key, source)
    return True


def frame_source(key: str, ssrc: int) -> tuple[int, int] | None:
    """``(uav, camera)`` of a frame received on ``key`` with ``ssrc``, or None when the SSRC is not a SkyNet
    camera's (RFC 3550 section 8: SSRCs are the sender's to choose, so the receiver checks them) or not one of the
    UAV whose camera key carried it (a UAV may write only its own keys)."""
    try:
        uav, camera = parse_ssrc(ssrc)
        key_uav = keys.parse(key).uav
    except ValueError:
        return None
    return (uav, camera) if key_uav == uav else None
