"""services.video.stream: pictures in, RTP out; bad pictures are errors, odd sizes are cropped to whole blocks."""

from __future__ import annotations

import socket

import cv2
import numpy as np
import pytest

from protocol.rtp import unpack_frame
from services.video.packetize import parse_jpeg
from services.video.stream import VideoStream, decode_picture


def test_decode_picture_grey_to_bgr_and_cropped_to_blocks() -> None:
    grey = cv2.imencode(".jpg", np.full((100, 130), 77, np.uint8))[1].tobytes()
    img = decode_picture(grey)
    assert img.shape == (96, 128, 3) and abs(int(img[..., 0].mean()) - 77) <= 2
    with pytest.raises(ValueError, match="cannot decode a truncated JPEG"):
        decode_picture(b"\xff\xd8 not really")


@pytest.mark.parametrize("codec", ["mjpeg", "h264"])
def test_stream_sends_rtp_to_its_port(codec: str) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        rx.settimeout(5)
        vs = VideoStream(codec, "127.0.0.1", rx.getsockname()[1], ssrc=0x534B0301)
        jpeg = cv2.imencode(".jpg", np.full((120, 160, 3), (10, 200, 30), np.uint8))[1].tobytes()
        n = vs.send(jpeg, 5.0)
        packets = [rx.recv(65535) for _ in range(n)]
        vs.close()
    headers = [unpack_frame(p)[0] for p in packets]
    assert n >= 1 and {h.ssrc for h in headers} == {0x534B0301} and headers[-1].marker
    assert {h.payload_type for h in headers} == {26 if codec == "mjpeg" else 96}
    with pytest.raises(ValueError):
        VideoStream("vp8", "127.0.0.1", 5600, ssrc=1)
    if codec == "mjpeg":  # the picture is re-encoded colour 4:2:0, the only kind RFC 2435 type 1 carries
        assert parse_jpeg(cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes()).type == 1
