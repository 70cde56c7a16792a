"""protocol.imagecodec: the size an image declares is read from its header and bounded before anything is decoded
(a few hundred bytes can declare 30000 x 30000 pixels, which OpenCV fills in seconds and a gigabyte)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from protocol.imagecodec import MAX_IMAGE_PIXELS, MAX_SCANS, decode_image, encode_jpeg, image_size


def _declaring(jpeg: bytes, w: int, h: int) -> bytes:
    """``jpeg`` with its baseline frame header (SOF0) rewritten to declare ``w`` x ``h``."""
    b = bytearray(jpeg)
    i = b.find(b"\xff\xc0")
    b[i + 5:i + 7], b[i + 7:i + 9] = h.to_bytes(2, "big"), w.to_bytes(2, "big")
    return bytes(b)


def test_the_declared_size_of_jpeg_png_and_progressive_jpeg():
    g = np.zeros((48, 64), np.uint8)
    assert image_size(encode_jpeg(g)) == (64, 48)
    assert image_size(encode_jpeg(np.zeros((30, 20, 3), np.uint8))) == (20, 30)
    assert image_size(cv2.imencode(".png", g)[1].tobytes()) == (64, 48)
    progressive = cv2.imencode(".jpg", g, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    assert b"\xff\xc2" in progressive and image_size(progressive) == (64, 48)
    assert image_size(memoryview(encode_jpeg(g))) == (64, 48)


@pytest.mark.parametrize(("data", "says"), [
    (b"\xff\xd8\xff\xda\x00\x08abcdef\xff\xd9", "marker 0xDA before its frame header"),
    (b"\xff\xd8" + b"\xff\xe0\x00\x02" * 300, "more than 256 segments before its frame header"),
    (b"\xff\xd8" + b"\xff" * 100_000, "without a start-of-frame"),
    (b"\xff\xd8\x00\x00\x00\x00", "header damaged"),
    (b"\xff\xd8\xff\xc0\x00\x11\x08", "start-of-frame segment truncated"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDX" + bytes(8), "without an IHDR"),
    (b"GIF89a", "neither a JPEG"),
])
def test_a_header_without_a_size_is_one_line(data, says):
    with pytest.raises(ValueError, match=says):
        image_size(data)


def test_a_small_file_declaring_a_huge_image_is_refused_before_decoding():
    bomb = _declaring(encode_jpeg(np.zeros((8, 8), np.uint8)), 30000, 30000)
    assert len(bomb) < 1000 and image_size(bomb) == (30000, 30000)
    with pytest.raises(ValueError, match=r"declares 30000 x 30000 px, beyond the 100 MP decoded at most"):
        decode_image(bomb)
    assert 30000 * 30000 > MAX_IMAGE_PIXELS
    with pytest.raises(ValueError, match="the JPEG is 30000 x 30000 px, its metadata says 640 x 480"):
        decode_image(bomb, grey=True, size=(640, 480))
    small = _declaring(encode_jpeg(np.zeros((8, 8), np.uint8)), 16, 8)
    with pytest.raises(ValueError, match="declares 16 x 8 px, beyond the 0.0001 MP"):
        decode_image(small, max_pixels=100)
    png = cv2.imencode(".png", np.zeros((8, 8), np.uint8))[1].tobytes()
    huge_png = png[:16] + (40000).to_bytes(4, "big") + (40000).to_bytes(4, "big") + png[24:]
    with pytest.raises(ValueError, match="the PNG declares 40000 x 40000 px"):
        decode_image(huge_png)


def test_a_frame_of_its_metadatas_size_decodes_at_every_reduction():
    g = np.random.default_rng(0).integers(0, 255, (480, 640), np.uint8)
    jpeg = encode_jpeg(g)
    for f in (1, 2, 4, 8):
        assert decode_image(jpeg, grey=True, reduce=f, size=(640, 480)).shape == (480 // f, 640 // f)


def test_a_header_that_hides_its_frame_header_from_a_parser_is_refused():
    """``FF 00`` where a marker should be: libjpeg skips it as garbage and takes the real frame header (30000 x
    30000), while a parser reading it as a segment jumped over that header to a 640 x 480 one hidden in a comment,
    so that the bomb matched its metadata (8 s, 1.8 GB)."""
    base = encode_jpeg(np.zeros((8, 8), np.uint8))
    i = base.find(b"\xff\xc0")
    n = int.from_bytes(base[i + 2:i + 4], "big")
    sof = base[i:i + 2 + n]
    real = sof[:5] + (30000).to_bytes(2, "big") + (30000).to_bytes(2, "big") + sof[9:]
    fake = sof[:5] + (480).to_bytes(2, "big") + (640).to_bytes(2, "big") + sof[9:]
    before = base[2:i] + real
    com = b"\xff\xfe" + (2 + 1 + len(fake)).to_bytes(2, "big") + b"x" + fake
    skip = 6 + len(before) + 4 + 1 - 4
    data = b"\xff\xd8\xff\x00" + skip.to_bytes(2, "big") + before + com + base[i + 2 + n:]
    with pytest.raises(ValueError, match="marker 0x00 before its frame header"):
        decode_image(data, grey=True, size=(640, 480))


def test_a_jpeg_of_many_empty_scans_is_refused_before_decoding():
    """libjpeg walks the whole frame once per scan, even an empty one: 5,000 ten-byte scans in a progressive
    4000 x 3000 file cost 4 s."""
    g = np.zeros((64, 64), np.uint8)
    prog = cv2.imencode(".jpg", g, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    assert decode_image(prog).shape == (64, 64)  # an encoder's progressive file: a handful of scans
    empty = b"\xff\xda\x00\x08\x01\x01\x00\x01\x3f\x00"
    many = prog[:-2] + empty * MAX_SCANS + b"\xff\xd9"
    with pytest.raises(ValueError, match=f"more than {MAX_SCANS} scans"):
        decode_image(many)


def test_exif_orientation_does_not_turn_the_pixels_and_a_shape_unlike_the_header_is_refused():
    """A 640 x 480 capture with an EXIF orientation of 6 decoded turned (480 x 640) under the size its metadata
    gave: the pixels are taken as sent."""
    import struct

    jpeg = encode_jpeg(np.random.default_rng(0).integers(0, 255, (480, 640), np.uint8))
    tiff = b"MM\x00\x2a" + struct.pack(">I", 8) + struct.pack(">H", 1) + struct.pack(">HHII", 0x0112, 3, 1, 6 << 16)
    tiff += struct.pack(">I", 0)
    app1 = b"\xff\xe1" + (2 + 6 + len(tiff)).to_bytes(2, "big") + b"Exif\x00\x00" + tiff
    turned = jpeg[:2] + app1 + jpeg[2:]
    assert image_size(turned) == (640, 480)
    for f in (1, 2):
        assert decode_image(turned, grey=True, reduce=f, size=(640, 480)).shape == (480 // f, 640 // f)
