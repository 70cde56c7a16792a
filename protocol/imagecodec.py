"""The image codec of the wire's frames: JPEG encoding and JPEG/PNG decoding (OpenCV).

Design notes: docs/imagery.md (protocol/imagecodec.py).
"""

from __future__ import annotations

import math
import re

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["MAX_IMAGE_PIXELS", "MAX_SCANS", "decode_image", "encode_jpeg", "image_size"]

#: the most pixels an image may declare to be decoded (a 100 MP medium-format frame; the project's captures are
#: 0.3-12 MP): a few hundred bytes can declare 30000 x 30000, which OpenCV would fill in seconds and a gigabyte
MAX_IMAGE_PIXELS = 100_000_000


def encode_jpeg(image: NDArray[np.uint8], quality: int = 85) -> bytes:
    """JPEG bytes of a ``uint8`` grey (H, W) or BGR (H, W, 3) image (``cv2.imencode``); ValueError on a
    non-image array or a quality outside 1..100."""
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


#: JPEG start-of-frame markers (ITU T.81 Table B.1: SOF0-SOF15 but DHT C4, JPG C8 and DAC CC)
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: the other marker segments a JPEG may hold before its frame header (ITU T.81 B.2.4, B.3.2, Table B.1: DHT,
#: DAC, DQT, DRI, DHP, EXP, APP0-15, COM); anything else there (0x00, a reserved code) is refused, since libjpeg
#: skips it as garbage while a parser would take it for a segment and jump over the real frame header
_TABLES = frozenset({0xC4, 0xCC, 0xDB, 0xDD, 0xDE, 0xDF, *range(0xE0, 0xF0), 0xFE})
_NOT_FILL = re.compile(rb"[^\xff]")
#: the most scans (start-of-scan markers) a JPEG may hold: libjpeg walks the whole frame once per scan even when
#: the scan is empty, so a progressive file of thousands of empty scans costs seconds (baseline: one scan per
#: component; a progressive encoder writes about ten)
MAX_SCANS = 32
#: the most marker segments before the frame header (a camera writes a dozen: APPn, DQT, DHT)
MAX_HEADER_SEGMENTS = 256


def image_size(data: bytes | bytearray | memoryview) -> tuple[int, int]:
    """The (width, height) a PNG (its IHDR chunk, RFC 2083 4.1.1) or a JPEG (its frame header, ITU T.81 B.2.2,
    after only the table and application segments B.2.4 allows before it) declares, read from its header without
    decoding; ValueError when there is none or the header holds anything else."""
    b = bytes(data) if not isinstance(data, bytes) else data
    if b[:8] == _PNG_SIGNATURE:
        if len(b) < 24 or b[12:16] != b"IHDR":
            raise ValueError("PNG without an IHDR chunk")
        return int.from_bytes(b[16:20], "big"), int.from_bytes(b[20:24], "big")
    if len(b) < 4 or b[0] != 0xFF or b[1] != 0xD8:
        raise ValueError("cannot decode: neither a JPEG (no start-of-image marker) nor a PNG (no signature)")
    i, n = 2, len(b)
    for _ in range(MAX_HEADER_SEGMENTS):
        if i + 4 > n:
            break
        if b[i] != 0xFF:
            raise ValueError(f"JPEG header damaged at byte {i}")
        m = _NOT_FILL.search(b, i + 1)  # fill bytes (B.1.1.2) may precede a marker
        if m is None:
            break
        i = m.start() - 1
        marker = b[i + 1]
        if marker in _SOF:
            if i + 9 > n or int.from_bytes(b[i + 2:i + 4], "big") < 8:
                raise ValueError("JPEG start-of-frame segment truncated")
            return int.from_bytes(b[i + 7:i + 9], "big"), int.from_bytes(b[i + 5:i + 7], "big")
        if marker not in _TABLES:
            raise ValueError(f"JPEG header damaged: marker 0x{marker:02X} before its frame header")
        length = int.from_bytes(b[i + 2:i + 4], "big")
        if length < 2:
            break
        i += 2 + length
    else:
        raise ValueError(f"JPEG with more than {MAX_HEADER_SEGMENTS} segments before its frame header")
    raise ValueError("JPEG without a start-of-frame segment")


#: cv2.imdecode flags of a grey image decoded at 1/2, 1/4, 1/8 of its size (JPEG: by the DCT, not a resize)
_REDUCED_GREY = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
                 8: cv2.IMREAD_REDUCED_GRAYSCALE_8}


def decode_image(data: bytes | bytearray | memoryview, grey: bool = False, reduce: int = 1,
                 size: tuple[int, int] | None = None, max_pixels: int = MAX_IMAGE_PIXELS) -> NDArray[np.uint8]:
    """The image of JPEG or PNG bytes (``cv2.imdecode``): grey or BGR as stored, or grey if ``grey``;
    ``reduce`` 2, 4 or 8 decodes it grey at that fraction of its size (libjpeg scales in the DCT, so a
    12 MP frame decodes at 1/4 in a fraction of the full decode's time).

    The one decoder of the project. JPEG must be complete (ITU T.81 start- and end-of-image markers:
    libjpeg would half-decode a truncated frame with only a warning), PNG start with its signature; the size
    its header declares (:func:`image_size`) must be ``size`` (width, height) when given (a frame's metadata)
    and at most ``max_pixels``, checked before anything is decoded; ValueError otherwise, or when the codec
    refuses them.
    """
    try:  # one copy at most, read by the header checks and the codec alike
        raw = data if isinstance(data, bytes) else memoryview(data).tobytes()
    except TypeError:
        raise ValueError(f"image data must be bytes, got {type(data).__name__}") from None
    if not raw:
        raise ValueError("cannot decode an empty image")
    kind = "PNG" if raw[:8] == _PNG_SIGNATURE else "JPEG"
    if kind == "JPEG" and raw[:2] == b"\xff\xd8" and b"\xff\xd9" not in raw[-64:]:
        raise ValueError("cannot decode a truncated JPEG: no end-of-image marker")
    w, h = image_size(raw)  # (neither signature: ValueError)
    if reduce not in _REDUCED_GREY:
        raise ValueError(f"reduce must be one of {sorted(_REDUCED_GREY)}, got {reduce!r}")
    if size is not None and (w, h) != tuple(size):
        raise ValueError(f"the {kind} is {w} x {h} px, its metadata says {size[0]} x {size[1]}")
    if w < 1 or h < 1:
        raise ValueError(f"the {kind} declares an empty image ({w} x {h} px)")
    if w * h > max_pixels:
        raise ValueError(f"the {kind} declares {w} x {h} px, beyond the {max_pixels / 1e6:g} MP decoded at most")
    if kind == "JPEG" and raw.count(b"\xff\xda") > MAX_SCANS:
        raise ValueError(f"the JPEG holds more than {MAX_SCANS} scans")
    flag = _REDUCED_GREY[reduce] if grey or reduce > 1 else cv2.IMREAD_UNCHANGED
    try:
        # the pixels as sent, not as EXIF turns them
        img = cv2.imdecode(np.frombuffer(raw, np.uint8), flag | cv2.IMREAD_IGNORE_ORIENTATION)
    except cv2.error:
        img = None
    if img is None:
        raise ValueError(f"cannot decode a corrupt {kind}")
    # libjpeg scales a JPEG to the size rounded up, OpenCV resizes a PNG to the size rounded down
    want = (math.ceil(h / reduce), math.ceil(w / reduce)) if kind == "JPEG" else (h // reduce, w // reduce)
    if img.shape[:2] != want:
        raise ValueError(f"the {kind} decoded to {img.shape[1]} x {img.shape[0]} px, its header declares {w} x {h}")
    return np.asarray(img, dtype=np.uint8)

