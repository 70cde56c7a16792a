"""The image codec of the wire's frames: JPEG encoding and JPEG/PNG decoding (OpenCV).

Design notes: docs/imagery.md (protocol/imagecodec.py).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["decode_image", "encode_jpeg"]


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


#: cv2.imdecode flags of a grey image decoded at 1/2, 1/4, 1/8 of its size (JPEG: by the DCT, not a resize)
_REDUCED_GREY = {1: cv2.IMREAD_GRAYSCALE, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
                 8: cv2.IMREAD_REDUCED_GRAYSCALE_8}


def decode_image(data: bytes | bytearray | memoryview, grey: bool = False, reduce: int = 1) -> NDArray[np.uint8]:
    """The image of JPEG or PNG bytes (``cv2.imdecode``): grey or BGR as stored, or grey if ``grey``;
    ``reduce`` 2, 4 or 8 decodes it grey at that fraction of its size (libjpeg scales in the DCT, so a
    12 MP frame decodes at 1/4 in a fraction of the full decode's time).

    The one decoder of the project. JPEG must be complete (ITU T.81 start- and end-of-image markers:
    libjpeg would half-decode a truncated frame with only a warning), PNG start with its signature;
    ValueError otherwise, or when the codec refuses them.
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
    return np.asarray(img, dtype=np.uint8)

