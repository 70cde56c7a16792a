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

The image itself is encoded and decoded here too (:func:`encode_jpeg`, :func:`decode_image`, OpenCV),
so that the camera, the detector and the ground side share one codec of the wire's images.
"""

from __future__ import annotations

import struct

import cv2
import numpy as np
from numpy.typing import NDArray

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


# ============================================================================ image encoding
def encode_jpeg(image: NDArray[np.uint8], quality: int = 85) -> bytes:
    """JPEG bytes of a ``uint8`` grey (H, W) or BGR (H, W, 3) image (``cv2.imencode``).

    Raises
    ------
    ValueError
        On a non-image array or a quality outside 1..100.
    """
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 1 <= quality <= 100:
        raise ValueError(f"JPEG quality must be an integer in 1..100, got {quality!r}")
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        raise ValueError("image must be a uint8 numpy array")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))) or image.size == 0:
        raise ValueError(f"image must be (H, W) or (H, W, 3), got shape {image.shape}")
    if max(image.shape[:2]) > 65500:
        raise ValueError(f"image of {image.shape[1]} x {image.shape[0]} px is too large for JPEG")
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"  # RFC 2083, section 3.1


#: cv2.imdecode flags of a grey image decoded at 1/2, 1/4, 1/8 of its size (JPEG: by the DCT, not a resize)
_REDUCED_GREY = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
                 8: cv2.IMREAD_REDUCED_GRAYSCALE_8}


def decode_image(data: bytes | bytearray | memoryview, grey: bool = False, reduce: int = 1) -> NDArray[np.uint8]:
    """The image of JPEG or PNG bytes (``cv2.imdecode``): grey or BGR as stored, or grey if ``grey``;
    ``reduce`` 2, 4 or 8 decodes it grey at that fraction of its size (libjpeg scales in the DCT,
    so a 12 MP frame decodes at 1/4 in a fraction of the full decode's time).

    The one decoder of the project (the camera's tests, the detector). JPEG must be complete
    (ITU T.81 start- and end-of-image markers: libjpeg would otherwise half-decode a truncated
    frame with only a warning); PNG must start with its signature.

    Raises
    ------
    ValueError
        When the bytes are not a complete JPEG or PNG, or the codec refuses them.
    """
    try:
        buf = np.frombuffer(data, np.uint8)
    except TypeError:
        raise ValueError(f"image data must be bytes, got {type(data).__name__}") from None
    if buf.size == 0:
        raise ValueError("cannot decode an empty image")
    if buf[:8].tobytes() == _PNG_SIGNATURE:
        kind = "PNG"
    elif buf.size >= 4 and buf[0] == 0xFF and buf[1] == 0xD8:
        kind = "JPEG"
        if b"\xff\xd9" not in buf[-64:].tobytes():
            raise ValueError("cannot decode a truncated JPEG: no end-of-image marker")
    else:
        raise ValueError("cannot decode: neither a JPEG (no start-of-image marker) nor a PNG (no signature)")
    if reduce not in _REDUCED_GREY:
        raise ValueError(f"reduce must be one of {sorted(_REDUCED_GREY)}, got {reduce!r}")
    flag = _REDUCED_GREY[reduce] if grey or reduce > 1 else cv2.IMREAD_UNCHANGED
    img = cv2.imdecode(buf, flag)
    if img is None:
        raise ValueError(f"cannot decode a corrupt {kind}")
    return img

