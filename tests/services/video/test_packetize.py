"""RFC 6184 and RFC 2435 packetisers against the RFCs' byte layouts (services.video.packetize)."""

from __future__ import annotations

import struct

import cv2
import numpy as np
import pytest

from protocol.rtp import JPEG_PAYLOAD_TYPE, RtpSender, unpack_frame
from services.video.packetize import H264Packetizer, JpegPacketizer, PayloadError, parse_jpeg, split_annexb


def test_split_annexb_both_start_codes() -> None:
    stream = b"\x00\x00\x00\x01\x67AB\x00\x00\x01\x68CD\x00\x00\x00\x01\x65" + b"x" * 5
    assert split_annexb(stream) == [b"\x67AB", b"\x68CD", b"\x65xxxxx"]
    with pytest.raises(PayloadError):
        split_annexb(b"no start code")


def test_h264_single_nal_and_fu_a_reassemble() -> None:
    big = bytes([0x65]) + bytes(range(256)) * 20  # an IDR slice of 5121 bytes, NRI 3
    au = b"\x00\x00\x00\x01\x67" + b"s" * 10 + b"\x00\x00\x00\x01\x68pp" + b"\x00\x00\x01" + big
    pk = H264Packetizer(RtpSender(7, payload_type=96, initial_seq=65535), mtu=1200)
    packets = pk.packetize(au, 1.0)
    assert all(len(p) <= 1200 for p in packets)
    parsed = [unpack_frame(p) for p in packets]
    assert [h.sequence for h, _ in parsed][:3] == [65535, 0, 1]
    assert {h.timestamp for h, _ in parsed} == {90_000} and {h.payload_type for h, _ in parsed} == {96}
    assert [h.marker for h, _ in parsed] == [False] * (len(parsed) - 1) + [True]  # 5.1: last packet of the AU
    assert bytes(parsed[0][1]) == b"\x67" + b"s" * 10 and bytes(parsed[1][1]) == b"\x68pp"
    frags = [bytes(p) for _, p in parsed[2:]]
    assert all(f[0] == (0x65 & 0xE0) | 28 for f in frags)  # FU indicator: F, NRI of the NAL, type 28
    assert frags[0][1] & 0xC0 == 0x80 and frags[-1][1] & 0xC0 == 0x40  # S on the first, E on the last
    assert all(f[1] & 0x1F == 5 for f in frags) and all(f[1] & 0xC0 == 0 for f in frags[1:-1])
    assert bytes([(frags[0][0] & 0xE0) | (frags[0][1] & 0x1F)]) + b"".join(f[2:] for f in frags) == big


def _jpeg(colour: bool = True, size=(240, 320)) -> bytes:
    img = np.zeros((*size, 3), np.uint8)
    img[..., 2] = 200
    img[40:80, 40:200] = (0, 255, 0)
    if not colour:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    ok, enc = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80, cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                         cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420])
    return enc.tobytes()


def test_rfc2435_headers_tables_and_offsets() -> None:
    jpeg = _jpeg()
    scan = parse_jpeg(jpeg)
    assert (scan.type, scan.width, scan.height, len(scan.qtables)) == (1, 320, 240, 128)
    packets = JpegPacketizer(RtpSender(9, payload_type=JPEG_PAYLOAD_TYPE, initial_seq=3), mtu=600).packetize(jpeg, 2.0)
    assert len(packets) > 2 and all(len(p) <= 600 for p in packets)
    data, expected_offset = b"", 0
    for n, p in enumerate(packets):
        h, payload = unpack_frame(p)
        payload = bytes(payload)
        assert (h.payload_type, h.timestamp, h.marker) == (26, 180_000, n == len(packets) - 1)
        ts_spec, off_hi, off_lo, typ, q, w8, h8 = struct.unpack_from("!BBHBBBB", payload)
        assert (ts_spec, (off_hi << 16) | off_lo, typ, q, w8, h8) == (0, expected_offset, 1, 255, 40, 30)
        body = payload[8:]
        if n == 0:  # 3.1.8: MBZ, precision, length, then the tables, in the first packet only
            assert struct.unpack_from("!BBH", body) == (0, 0, 128) and body[4:132] == scan.qtables
            body = body[132:]
        data += body
        expected_offset += len(body)
    assert data == scan.scan and not data.endswith(b"\xff\xd9")


@pytest.mark.parametrize("what, jpeg, needle", [
    ("grey", _jpeg(colour=False), "three-component"),
    ("odd size", _jpeg(size=(100, 130)), "multiples of 8"),
    ("not jpeg", b"GIF89a....", "SOI"),
    ("truncated", _jpeg()[:300], "truncated"),
])
def test_rfc2435_refuses_what_it_cannot_carry(what, jpeg, needle) -> None:
    with pytest.raises(PayloadError, match=needle):
        parse_jpeg(jpeg)
    with pytest.raises(ValueError):
        JpegPacketizer(RtpSender(1, payload_type=96))  # RFC 2435 is the static type 26
