"""RTP payload formats for standard players: H.264 (RFC 6184) and JPEG (RFC 2435). Pure, no I/O.

Design notes: docs/operator-view.md (services/video/packetize.py).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from protocol.rtp import JPEG_PAYLOAD_TYPE, RTP_HEADER_LENGTH, RtpSender, media_timestamp

__all__ = ["DEFAULT_MTU", "H264_PAYLOAD_TYPE", "JpegScan", "PayloadError", "H264Packetizer", "JpegPacketizer",
           "parse_jpeg", "split_annexb"]

DEFAULT_MTU = 1200  # bytes of one RTP packet (header included): fits any path MTU of 1280 (IPv6) with UDP/IP
H264_PAYLOAD_TYPE = 96  # dynamic (RFC 3551 section 3), named H264/90000 in the SDP (RFC 6184 section 8.2.1)
FU_A = 28
_JPEG_MAIN = struct.Struct("!BBHBBBB")  # type-specific, offset (24 bits as B + H), type, Q, width/8, height/8


class PayloadError(ValueError):
    """An encoded picture that this payload format cannot carry."""


def split_annexb(stream: bytes) -> list[bytes]:
    """NAL units of an H.264 Annex B byte stream (start codes ``00 00 01`` or ``00 00 00 01``).

    Leading zero bytes of a 4-byte start code and trailing zeros of a NAL unit (trailing_zero_8bits,
    ITU-T H.264 B.1) are dropped.
    """
    data = bytes(stream)
    nals: list[bytes] = []
    i = data.find(b"\x00\x00\x01")
    if i < 0:
        raise PayloadError("no Annex B start code in the H.264 access unit")
    while i >= 0:
        start = i + 3
        j = data.find(b"\x00\x00\x01", start)
        # the zeros before the next start code are its leading zero or trailing_zero_8bits, not NAL bytes
        nal = data[start:j].rstrip(b"\x00") if j >= 0 else data[start:]
        if nal:
            nals.append(nal)
        i = j
    return nals


class H264Packetizer:
    """RFC 6184 packetisation-mode 1 of one stream (one SSRC, one sequence-number space)."""

    def __init__(self, sender: RtpSender, mtu: int = DEFAULT_MTU):
        if mtu < RTP_HEADER_LENGTH + 3:
            raise ValueError(f"mtu must leave room for a FU-A fragment, got {mtu}")
        self.sender, self.mtu = sender, int(mtu)

    def packetize(self, access_unit: bytes, capture_time_s: float) -> list[bytes]:
        """RTP packets of one access unit (Annex B), marker on the last (RFC 6184 section 5.1)."""
        room = self.mtu - RTP_HEADER_LENGTH
        payloads: list[bytes] = []
        for nal in split_annexb(access_unit):
            if len(nal) <= room:
                payloads.append(nal)  # single NAL unit packet (5.6)
                continue
            indicator = (nal[0] & 0xE0) | FU_A
            nal_type = nal[0] & 0x1F
            body = nal[1:]
            step = room - 2
            for k in range(0, len(body), step):
                first, last = k == 0, k + step >= len(body)
                header = (0x80 if first else 0) | (0x40 if last else 0) | nal_type
                payloads.append(bytes((indicator, header)) + body[k:k + step])
        return [self.sender.frame(p, capture_time_s, marker=(n == len(payloads) - 1)) for n, p in enumerate(payloads)]


@dataclass(frozen=True)
class JpegScan:
    """What RFC 2435 carries of one JFIF: type, size in 8-pixel blocks, quantisation tables, scan data."""

    type: int  # 0 = 4:2:2, 1 = 4:2:0
    width: int
    height: int
    qtables: bytes  # 64 bytes per table, in the order of their ids (luma, chroma), zig-zag as in DQT
    scan: bytes


def _segments(data: bytes):
    if data[:2] != b"\xff\xd8":
        raise PayloadError("not a JPEG file (no SOI marker)")
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            raise PayloadError(f"JPEG marker expected at byte {pos}")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        (length,) = struct.unpack_from("!H", data, pos + 2)
        if length < 2 or pos + 2 + length > len(data):
            raise PayloadError(f"JPEG segment {marker:#04x} at byte {pos} is truncated")
        yield marker, data[pos + 4:pos + 2 + length], pos + 2 + length
        if marker == 0xDA:  # SOS: entropy-coded data follows
            return
        pos += 2 + length
    raise PayloadError("JPEG has no SOS segment")


def parse_jpeg(jpeg: bytes) -> JpegScan:
    """The RFC 2435 view of a baseline JFIF; :class:`PayloadError` for what RFC 2435 cannot carry."""
    data = bytes(jpeg)
    tables: dict[int, bytes] = {}
    sof = None
    scan_start = None
    for marker, body, end in _segments(data):
        if marker == 0xDB:  # DQT: one or more tables
            k = 0
            while k < len(body):
                pq, tq = body[k] >> 4, body[k] & 0x0F
                if pq != 0:
                    raise PayloadError("16-bit quantisation tables are not supported (RFC 2435 precision 0 only)")
                tables[tq] = body[k + 1:k + 65]
                k += 65
        elif marker == 0xC0:
            sof = body
        elif marker in (0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            raise PayloadError(f"only baseline JPEG (SOF0) is carried by RFC 2435, got SOF{marker - 0xC0}")
        elif marker == 0xDD:
            raise PayloadError("restart intervals (DRI) are not supported by this packetiser")
        elif marker == 0xDA:
            scan_start = end
    if sof is None:
        raise PayloadError("JPEG has no SOF0 segment")
    precision, height, width, ncomp = struct.unpack_from("!BHHB", sof)
    if precision != 8 or ncomp != 3:
        raise PayloadError(f"RFC 2435 carries 8-bit three-component (YUV) JPEG, got {precision}-bit, {ncomp} components")
    comps = [(sof[6 + 3 * i], sof[7 + 3 * i], sof[8 + 3 * i]) for i in range(3)]
    sampling = [c[1] for c in comps]
    if sampling[1:] != [0x11, 0x11] or sampling[0] not in (0x22, 0x21):
        raise PayloadError(f"RFC 2435 types 0/1 need luma 2x1 or 2x2 and chroma 1x1, got {[hex(s) for s in sampling]}")
    if width % 8 or height % 8 or not 0 < width <= 2040 or not 0 < height <= 2040:
        raise PayloadError(f"RFC 2435 needs width and height multiples of 8 up to 2040, got {width}x{height}")
    ids = sorted({c[2] for c in comps})
    if any(i not in tables for i in ids):
        raise PayloadError("a component refers to a quantisation table the JPEG does not define")
    end = len(data)
    if data[end - 2:end] == b"\xff\xd9":
        end -= 2
    return JpegScan(type=1 if sampling[0] == 0x22 else 0, width=width, height=height,
                    qtables=b"".join(tables[i] for i in ids), scan=data[scan_start:end])


class JpegPacketizer:
    """RFC 2435 packetisation of one stream, in-band tables (Q = 255)."""

    def __init__(self, sender: RtpSender, mtu: int = DEFAULT_MTU):
        if sender.payload_type != JPEG_PAYLOAD_TYPE:
            raise ValueError(f"RFC 2435 streams use the static payload type 26, got {sender.payload_type}")
        if mtu < RTP_HEADER_LENGTH + 8 + 4 + 128 + 1:
            raise ValueError(f"mtu must hold the JPEG and quantisation-table headers and tables, got {mtu}")
        self.sender, self.mtu = sender, int(mtu)

    def packetize(self, jpeg: bytes, capture_time_s: float) -> list[bytes]:
        scan = parse_jpeg(jpeg)
        media_timestamp(capture_time_s)  # validates the time before any sequence number is used
        qheader = struct.pack("!BBH", 0, 0, len(scan.qtables)) + scan.qtables
        packets: list[bytes] = []
        offset, total = 0, len(scan.scan)
        while offset < total or not packets:
            extra = qheader if offset == 0 else b""
            room = self.mtu - RTP_HEADER_LENGTH - _JPEG_MAIN.size - len(extra)
            chunk = scan.scan[offset:offset + room]
            main = _JPEG_MAIN.pack(0, offset >> 16, offset & 0xFFFF, scan.type, 255, scan.width // 8, scan.height // 8)
            last = offset + len(chunk) >= total
            packets.append(self.sender.frame(main + extra + chunk, capture_time_s, marker=last))
            offset += len(chunk)
        return packets
