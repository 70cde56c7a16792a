"""``skynet video`` end to end: bus preview frames in, a real decoder (FFmpeg via PyAV) reads the SDP.

A publisher puts numbered colour pictures on ``uav/2/preview`` in the bus's own frame format; the
``skynet video`` process sends them as RTP to loopback; FFmpeg's SDP demuxer (through PyAV)
depacketises and decodes them. Each picture carries its number as an 8-bit bar code, so the test
checks the decoded size, the colour, and that the pictures arrive in order with the RTP
timestamps of their capture times.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.imagery import pack_image
from protocol.links import IMAGERY
from protocol.messages import ImageMeta, Intrinsics
from protocol.rtp import RtpSender, ssrc_for
from services.orchestration.process import free_port

av = pytest.importorskip("av", reason="PyAV (the av wheel) decodes the streams")

FLEET = "test"
W, H, BITS, WANTED = 320, 240, 8, 12


def picture(i: int) -> np.ndarray:
    img = np.zeros((H, W, 3), np.uint8)
    img[:] = (40, 40, 200)  # red in BGR: the camera has colour
    for b in range(BITS):
        img[0:40, b * 40:(b + 1) * 40] = 255 if (i >> b) & 1 else 0
    return img


def read_number(img: np.ndarray) -> int:
    grey = img.mean(axis=2)
    return sum(1 << b for b in range(BITS) if grey[8:32, b * 40 + 8:b * 40 + 32].mean() > 128)


def _meta(i: int, stamp: float) -> ImageMeta:
    return ImageMeta(uav=2, capture_id=0, t=float(i), stamp=stamp, cam_pos=(0.0, 0.0, 5.0),
                     cam_rot=(1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0),
                     intrinsics=Intrinsics(width=W, height=H, fx=300.0, fy=300.0, cx=160.0, cy=120.0))


@pytest.mark.parametrize("codec", ["h264", "mjpeg"])
def test_video_service_streams_a_uav_preview_to_a_real_decoder(group, gateway, tmp_path: Path, codec: str) -> None:
    base = free_port() & ~1  # even; UAV 2's preview goes to base + 2
    sdp_dir = tmp_path / "sdp"
    svc = group.start("video", ["video", "--fleet", FLEET, "--multilink", "--codec", codec, "--preview-port", str(base),
                                "--uavs", "2", "--sdp-dir", str(sdp_dir),
                                *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    sdp_file = sdp_dir / "uav2-preview.sdp"
    text = sdp_file.read_text()
    assert f"m=video {base + 2} RTP/AVP" in text and ("H264/90000" if codec == "h264" else "JPEG/90000") in text

    decoded: list[tuple[int, int | None, tuple, tuple]] = []
    errors: list[BaseException] = []

    def receive() -> None:
        try:
            with av.open(str(sdp_file), format="sdp", timeout=20,
                         options={"protocol_whitelist": "file,udp,rtp", "reorder_queue_size": "0"}) as c:
                for frame in c.decode(video=0):
                    img = frame.to_ndarray(format="bgr24")
                    decoded.append((read_number(img), frame.pts, img.shape, tuple(img[120:200, 40:280].mean(axis=(0, 1)))))
                    if len(decoded) >= WANTED:
                        return
        except BaseException as exc:  # noqa: BLE001 - handed to the test thread
            errors.append(exc)

    rx = threading.Thread(target=receive, daemon=True)
    rx.start()
    t0 = time.time()
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uav") as uav:
        pub = uav.publisher(keys.preview(FLEET, 2), IMAGERY)
        sender = RtpSender(ssrc_for(2, 1))
        pub.put_bytes(sender.frame(b"", time.time(), marker=False))  # the announce frame: skipped, not an error
        ok, spoof = cv2.imencode(".jpg", picture(0))
        forged = _meta(0, time.time()).model_copy(update={"uav": 3})  # speaking for UAV 3 on UAV 2's key
        pub.put_bytes(pack_image(RtpSender(ssrc_for(3, 1)), forged, spoof.tobytes(), time.time()))
        i = 0
        # a live source: pictures keep coming until the decoder has enough (it may join late)
        while rx.is_alive() and i < 400:
            stamp = t0 + 0.1 * i
            ok, jpeg = cv2.imencode(".jpg", picture(i), [cv2.IMWRITE_JPEG_QUALITY, 90])
            pub.put_bytes(pack_image(sender, _meta(i, stamp), jpeg.tobytes(), stamp))
            i += 1
            time.sleep(0.05)
    rx.join(5)
    assert not errors, errors
    assert not (sdp_dir / "uav3-preview.sdp").exists()  # the forged picture opened no stream for UAV 3
    assert len(decoded) >= WANTED, (len(decoded), "\n".join(svc.lines))
    numbers = [n for n, *_ in decoded]
    assert all(b > a for a, b in zip(numbers, numbers[1:])), numbers  # in order
    assert all(shape == (H, W, 3) for *_, shape, _ in decoded)
    b, g, r = decoded[-1][3]
    assert r > 150 and b < 90 and g < 90, decoded[-1][3]  # still red: colour survives
    # the RTP timestamps are the capture times (0.1 s apart = 9000 ticks of 90 kHz)
    with_pts = [(n, pts) for n, pts, *_ in decoded if pts is not None]
    assert len(with_pts) >= WANTED - 2
    (n0, p0) = with_pts[0]
    # (within one tick: wall-clock stamps near 1.8e9 s carry ~0.02 tick of float error, which rounding to the
    # nearest tick can turn into one)
    assert all(abs(pts - p0 - (n - n0) * 9000) <= 1 for n, pts in with_pts), with_pts
