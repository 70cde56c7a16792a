"""One outgoing video stream: bus JPEG -> picture -> H.264 (PyAV/libx264) or RFC 2435 JPEG -> RTP/UDP.

Design notes: docs/operator-view.md (services/video/stream.py).
"""

from __future__ import annotations

import socket
import threading
from fractions import Fraction
from typing import Literal

import cv2
import numpy as np

from protocol.imagecodec import decode_image
from protocol.rtp import JPEG_PAYLOAD_TYPE, RtpSender

from .packetize import DEFAULT_MTU, H264_PAYLOAD_TYPE, H264Packetizer, JpegPacketizer

Codec = Literal["h264", "mjpeg"]


def decode_picture(jpeg: bytes) -> np.ndarray:
    """The BGR picture of a JPEG (grey JPEGs become three equal channels); ValueError if undecodable."""
    img: np.ndarray = decode_image(jpeg)  # its declared size bounded before it is decoded
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    h, w = img.shape[:2]
    if w % 8 or h % 8:  # both payload formats want whole 8x8 blocks (4:2:0 H.264 wants even sizes)
        img = np.ascontiguousarray(img[: h - h % 8, : w - w % 8])
    return img


class H264Encoder:
    """libx264 through PyAV: BGR pictures in, Annex B access units out (one per picture)."""

    def __init__(self, width: int, height: int, gop: int = 4, crf: int = 23):
        import av

        self.width, self.height = width, height
        ctx = av.CodecContext.create("libx264", "w")
        ctx.width, ctx.height, ctx.pix_fmt = width, height, "yuv420p"
        ctx.time_base = Fraction(1, 90_000)
        ctx.gop_size = int(gop)
        # constant quality, not a bit rate: with a 90 kHz time base and irregular capture times a
        # bit-rate target is spread over 90 000 "frames" a second and every picture starves
        ctx.options = {"preset": "ultrafast", "tune": "zerolatency", "profile": "baseline", "crf": str(int(crf)),
                       "x264-params": f"keyint={int(gop)}:min-keyint={int(gop)}:scenecut=0:repeat-headers=1"}
        self._ctx = ctx
        self._av = av
        self._last_pts: int | None = None

    def encode(self, bgr: np.ndarray, pts: int) -> bytes:
        if self._last_pts is not None and pts <= self._last_pts:
            pts = self._last_pts + 1  # libx264 wants strictly increasing times
        self._last_pts = pts
        frame = self._av.VideoFrame.from_ndarray(bgr, format="bgr24").reformat(format="yuv420p")
        frame.pts = pts
        frame.time_base = self._ctx.time_base
        return b"".join(bytes(p) for p in self._ctx.encode(frame))


class VideoStream:
    """Encodes and sends one camera's pictures to ``(host, port)``; thread-safe :meth:`send`."""

    def __init__(self, codec: Codec, host: str, port: int, ssrc: int, mtu: int = DEFAULT_MTU, gop: int = 4,
                 quality: int = 80, sock: socket.socket | None = None):
        if codec not in ("h264", "mjpeg"):
            raise ValueError(f"codec must be h264 or mjpeg, got {codec!r}")
        self.codec, self.addr, self.gop, self.quality = codec, (host, int(port)), gop, int(quality)
        pt = H264_PAYLOAD_TYPE if codec == "h264" else JPEG_PAYLOAD_TYPE
        self.sender = RtpSender(ssrc, payload_type=pt)
        self.packetizer = (H264Packetizer if codec == "h264" else JpegPacketizer)(self.sender, mtu)
        self.sock = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._own_sock = sock is None
        self._encoder: H264Encoder | None = None
        self._t0: float | None = None
        self._lock = threading.Lock()
        self.pictures = self.packets = self.octets = self.errors = 0

    def send(self, jpeg: bytes, capture_time_s: float) -> int:
        """Encode one picture, send its packets; the number of packets sent."""
        picture = decode_picture(jpeg)
        with self._lock:
            if self.codec == "h264":
                h, w = picture.shape[:2]
                if self._encoder is None or (self._encoder.width, self._encoder.height) != (w, h):
                    self._encoder = H264Encoder(w, h, gop=self.gop)
                if self._t0 is None:
                    self._t0 = capture_time_s
                au = self._encoder.encode(picture, round((capture_time_s - self._t0) * 90_000))
                packets = self.packetizer.packetize(au, capture_time_s) if au else []
            else:
                ok, enc = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, self.quality,
                                                         cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
                                                         cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420])
                if not ok:
                    raise ValueError("JPEG encoding failed")
                packets = self.packetizer.packetize(enc.tobytes(), capture_time_s)
            for p in packets:
                self.sock.sendto(p, self.addr)
                self.octets += len(p)
            self.pictures += 1
            self.packets += len(packets)
        return len(packets)

    def close(self) -> None:
        if self._own_sock:
            self.sock.close()
