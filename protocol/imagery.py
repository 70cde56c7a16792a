"""The imagery frame: an RTP packet whose payload carries the frame metadata and the image.

Design notes: docs/imagery.md (protocol/imagery.py).
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
