"""The imagery frame: an RTP packet whose payload carries the frame metadata and the image.

Layout of one sample on ``skynet/<fleet>/uav/<id>/camera``::

    +------------------------+---------------+-------------------------+----------------------+
    | RTP fixed header (12 B)| meta length   | ImageMeta (codec bytes) | encoded image (JPEG) |
    | RFC 3550, PT 96        | uint16, big   |  msgpack envelope       |                      |
    +------------------------+---------------+-------------------------+----------------------+

Any RTP parser reads the header (sequence, 90 kHz media timestamp of the capture, SSRC of the
camera, marker set on every frame since one frame is one packet); the payload then starts
with the length-prefixed metadata, so a receiver needs no second message to place the image.

This is not the RFC 2435 JPEG payload (no JPEG payload header, a whole JFIF file, metadata in
front), so the frames carry the dynamic payload type 96 with the encoding name
``x-skynet-frame/90000`` (:data:`protocol.rtp.SKYNET_PAYLOAD_TYPE`), never the static JPEG type 26.
``skynet video`` (:mod:`services.video`) turns them into standard RTP (RFC 2435, RFC 6184).
The image itself is encoded and decoded by :mod:`protocol.imagecodec`.
"""

from __future__ import annotations

import struct

from . import codec
from .messages import ImageMeta
from .rtp import RtpHeader, RtpSender, unpack_frame

_LEN = struct.Struct("!H")


def pack_image(sender: RtpSender, meta: ImageMeta, image: bytes, capture_time_s: float) -> bytes:
    """One imagery sample: RTP header + length-prefixed metadata + encoded image."""
    meta_bytes = codec.encode(meta)
    if len(meta_bytes) > 0xFFFF:
        raise ValueError("image metadata larger than 64 KiB")
    return sender.frame(_LEN.pack(len(meta_bytes)) + meta_bytes + bytes(image), capture_time_s)


def split_payload(payload: bytes | memoryview) -> tuple[ImageMeta, memoryview]:
    """Metadata and image bytes of an RTP payload; raises :class:`codec.CodecError`."""
    view = memoryview(payload)
    if len(view) < _LEN.size:
        raise codec.CodecError("bad-bytes", "imagery payload shorter than its length prefix")
    (n,) = _LEN.unpack_from(view)
    if len(view) < _LEN.size + n:
        raise codec.CodecError("bad-bytes", f"imagery metadata truncated ({len(view) - 2} < {n} bytes)")
    meta = codec.decode(view[_LEN.size:_LEN.size + n], ImageMeta)
    return meta, view[_LEN.size + n:]


def unpack_image(data: bytes | memoryview) -> tuple[RtpHeader, ImageMeta, memoryview]:
    """Header, metadata and image of one sample; raises ``RtpError`` or ``CodecError`` (both ValueError)."""
    header, payload = unpack_frame(data)
    meta, image = split_payload(payload)
    return header, meta, image
