"""The RTP streams of ``skynet video`` through GStreamer's own depayloaders (Debian's gstreamer1.0-plugins-good).

``rtpjpegdepay`` is the element that decoded 0 of 20 of the bus's old frames ("no header"); here it
and ``jpegdec`` must turn every RFC 2435 picture into a 320x240 picture (the caps filter refuses
any other size), in order. ``rtph264depay`` must rebuild whole access units (alignment=au) from the
RFC 6184 single-NAL and FU-A packets, which FFmpeg's decoder (PyAV) then decodes, in order.
"""

from __future__ import annotations

import shutil
import subprocess
import threading
import time

import cv2
import numpy as np
import pytest

from services.orchestration.process import free_port
from services.video.stream import VideoStream
from tests.services.video.test_service import H, W, picture, read_number

GST = shutil.which("gst-launch-1.0")
pytestmark = pytest.mark.skipif(GST is None, reason="needs Debian's gstreamer1.0-tools and -plugins-good (.ci/run installs them)")
WANTED = 10


def _gst(port: int, caps: str, *elements: str) -> subprocess.Popen:
    return subprocess.Popen([GST, "-q", "udpsrc", f"port={port}", f"caps={caps}", *elements],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _stream_until(vs: VideoStream, done) -> int:
    t0, i = time.time(), 0
    while not done() and i < 300:  # a live source: pictures keep coming until the pipeline has enough
        ok, jpeg = cv2.imencode(".jpg", picture(i), [cv2.IMWRITE_JPEG_QUALITY, 90])
        vs.send(jpeg.tobytes(), t0 + 0.1 * i)
        i += 1
        time.sleep(0.04)
    return i


def test_gstreamer_rtpjpegdepay_decodes_the_rfc2435_stream() -> None:
    port = free_port() & ~1
    proc = _gst(port, "application/x-rtp,media=video,clock-rate=90000,encoding-name=JPEG,payload=26",
                "!", "rtpjpegdepay", "!", "jpegdec", "!", "videoconvert", "!",
                f"video/x-raw,format=BGR,width={W},height={H}", "!", "fdsink", "fd=1")
    numbers: list[int] = []

    def read() -> None:
        while len(numbers) < WANTED:
            buf = proc.stdout.read(W * H * 3)
            if len(buf) < W * H * 3:
                return
            numbers.append(read_number(np.frombuffer(buf, np.uint8).reshape(H, W, 3)))

    t = threading.Thread(target=read, daemon=True)
    t.start()
    vs = VideoStream("mjpeg", "127.0.0.1", port, 0x534B0101)
    try:
        time.sleep(0.5)
        _stream_until(vs, lambda: len(numbers) >= WANTED or proc.poll() is not None)
        t.join(5)
    finally:
        vs.close()
        proc.kill()
        err = proc.communicate()[1].decode(errors="replace")
    assert len(numbers) >= WANTED, err
    assert all(b == a + 1 for a, b in zip(numbers, numbers[1:])), numbers  # every picture, in order


def test_gstreamer_rtph264depay_rebuilds_access_units() -> None:
    av = pytest.importorskip("av")
    port = free_port() & ~1
    proc = _gst(port, "application/x-rtp,media=video,clock-rate=90000,encoding-name=H264,payload=96",
                "!", "rtph264depay", "!", "video/x-h264,stream-format=byte-stream,alignment=au", "!", "fdsink", "fd=1")
    decoder = av.CodecContext.create("h264", "r")
    decoded: list[tuple[int, tuple]] = []

    def read() -> None:
        while len(decoded) < WANTED:
            chunk = proc.stdout.read1(65536)
            if not chunk:
                return
            for packet in decoder.parse(chunk):
                for frame in decoder.decode(packet):
                    img = frame.to_ndarray(format="bgr24")
                    decoded.append((read_number(img), img.shape))

    t = threading.Thread(target=read, daemon=True)
    t.start()
    vs = VideoStream("h264", "127.0.0.1", port, 0x534B0101, mtu=600)  # small packets: FU-A fragments
    try:
        time.sleep(0.5)
        _stream_until(vs, lambda: len(decoded) >= WANTED or proc.poll() is not None)
        t.join(5)
    finally:
        vs.close()
        proc.kill()
        err = proc.communicate()[1].decode(errors="replace")
    assert len(decoded) >= WANTED, err
    numbers = [n for n, _ in decoded]
    assert all(shape == (H, W, 3) for _, shape in decoded)
    assert all(b == a + 1 for a, b in zip(numbers, numbers[1:])), numbers
