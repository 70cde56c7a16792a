"""The detector service's jitter-to-report path (services.detector.service.DetectorService) on the in-memory bus
(protocol.membus), with the detection run in this process instead of worker processes: frames out of order,
a lost frame released after the playout delay, a foreign SSRC, each to its defect report or its counter. The
same service over real processes and Zenoh: tests/services/detector/test_service.py."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from edge.world.surface import crack_image
from protocol import keys
from protocol.imagery import pack_image
from protocol.links import IMAGERY
from protocol.membus import MemBus, MemNetwork
from protocol.messages import DefectReport, ImageMeta, Intrinsics
from protocol.rtp import RtpSender, ssrc_for
from services.detector import service as service_mod
from services.detector.pool import analyse_frame
from tests.conftest import wait_until

FLEET = "det"


class InlinePool:
    """The detector pool's interface, detecting in the calling thread (the worker function itself)."""

    def __init__(self, workers: int = 1, context: str = "spawn", max_pixels: int | None = None) -> None:
        self.max_pixels, self.workers, self.crashes = max_pixels, workers, 0

    def warm(self, timeout: float = 60.0, method: str = "it+r") -> list[int]:
        return []

    def analyse(self, meta, image, method, ssrc, seq) -> DefectReport:
        return analyse_frame(meta, bytes(image), method, ssrc, seq, self.max_pixels)

    def close(self) -> None:
        pass


def meta(uav: int, capture_id: int) -> ImageMeta:
    return ImageMeta(uav=uav, capture_id=capture_id, t=float(capture_id), stamp=time.time(), cam_pos=(10.0, 0.0, 20.0),
                     cam_rot=(1, 0, 0, 0, 0, 1, 0, -1, 0),
                     intrinsics=Intrinsics(width=320, height=240, fx=500, fy=500, cx=160, cy=120), range_m=5.0)


@pytest.fixture
def rig(monkeypatch):
    monkeypatch.setattr(service_mod, "DetectorPool", InlinePool)
    net = MemNetwork()
    det_bus, uav = MemBus(net, FLEET, "detector"), MemBus(net, FLEET, "uav2")
    det = service_mod.DetectorService(det_bus, method="it", workers=1, playout_delay_s=0.05, recover=False)
    reports: list[DefectReport] = []
    uav.subscribe(keys.defects(FLEET), lambda m, s: reports.append(m), expect=DefectReport)
    rng = np.random.default_rng(5)
    frames = {}
    sender = RtpSender(ssrc_for(2))
    for cid in range(4):
        grey, _ = crack_image((240, 320), rng, n_cracks=2)
        jpeg = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes()
        frames[cid] = pack_image(sender, meta(2, cid), jpeg, time.time())
    yield det, uav.publisher(keys.camera(FLEET, 2), IMAGERY), frames, reports
    det.close()


def test_frames_out_of_order_are_reordered_and_each_is_reported(rig):
    det, pub, frames, reports = rig
    for cid in (0, 2, 1, 3):
        pub.put_bytes(frames[cid])
    assert wait_until(lambda: len(reports) == 4, 30), reports
    assert sorted(r.capture_id for r in reports) == [0, 1, 2, 3]
    assert all(r.ok and r.uav == 2 and r.frame is not None and r.defects for r in reports)
    m = det.stats().metrics
    assert m["uav2.cam0.delivered"] == 4 and m["uav2.cam0.reordered"] >= 1 and m["uav2.cam0.lost"] == 0


def test_a_lost_frame_holds_the_next_one_until_the_playout_delay_and_is_counted_lost(rig):
    det, pub, frames, reports = rig
    pub.put_bytes(frames[0])
    pub.put_bytes(frames[2])  # frame 1 never comes
    assert wait_until(lambda: len(reports) == 1, 30)
    time.sleep(0.1)  # past the 50 ms playout delay
    det.poll()
    assert wait_until(lambda: len(reports) == 2, 30)
    assert sorted(r.capture_id for r in reports) == [0, 2]
    assert det.stats().metrics["uav2.cam0.lost"] == 1


def test_garbage_and_a_foreign_camera_on_a_uavs_key_are_counted_not_reported(rig):
    det, pub, frames, reports = rig
    pub.put_bytes(b"\x00\x01 not rtp")
    forged = pack_image(RtpSender(ssrc_for(3)), meta(3, 7), b"\xff\xd8", time.time())  # UAV 3's camera on UAV 2's key
    pub.put_bytes(forged)
    pub.put_bytes(frames[0])
    assert wait_until(lambda: len(reports) == 1, 30)
    time.sleep(0.2)
    assert [r.capture_id for r in reports] == [0]
    assert det.counts["bad-rtp"] == 1 and det.counts["bad-ssrc"] == 1
