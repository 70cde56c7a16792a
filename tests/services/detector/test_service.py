"""The detector service end to end over the real bus (issue 5): frames in, reports out, corrupt frames counted."""

import time

import cv2
import numpy as np

from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.imagery import pack_image
from protocol.links import IMAGERY
from protocol.messages import DefectReport, ImageMeta, Intrinsics, LinkStats
from protocol.rtp import RtpSender, ssrc_for
from edge.surface import crack_image

FLEET = "test"


def _meta(uav, capture_id, w, h):
    # a camera 5 m in front of a wall, looking north (+y): x right = east, y down, z forward = north
    rot = (1, 0, 0, 0, 0, 1, 0, -1, 0)
    return ImageMeta(uav=uav, capture_id=capture_id, t=capture_id, stamp=time.time(), cam_pos=(10.0, 0.0, 20.0),
                     cam_rot=rot, intrinsics=Intrinsics(width=w, height=h, fx=500, fy=500, cx=w / 2, cy=h / 2),
                     range_m=5.0)


def test_detector_service_frames_in_reports_out(group, gateway):
    svc = group.start("detector", ["detector", "--fleet", FLEET, "--multilink",
                                   *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_for("detector up", 30), "\n".join(svc.lines)
    reports: list[DefectReport] = []
    stats: list[LinkStats] = []
    rng = np.random.default_rng(3)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uav") as uav:
        uav.subscribe(keys.defects(FLEET), lambda m, s: reports.append(m), expect=DefectReport)
        uav.subscribe(keys.rcu_stats(FLEET, "detector"), lambda m, s: stats.append(m), expect=LinkStats)
        deadline = time.monotonic() + 10
        while not uav.alive(keys.rcu_alive(FLEET, "detector")) and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.5)
        pub = uav.publisher(keys.camera(FLEET, 2), IMAGERY)
        sender = RtpSender(ssrc_for(2), initial_seq=65533)  # wraps during the test
        masks = {}
        for cid in range(4):
            grey, mask = crack_image((240, 320), rng, n_cracks=2)
            masks[cid] = mask
            ok, jpeg = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 90])
            pub.put_bytes(pack_image(sender, _meta(2, cid, 320, 240), jpeg.tobytes(), time.time()))
            time.sleep(0.1)
        pub.put_bytes(pack_image(sender, _meta(2, 99, 320, 240), b"\xff\xd8 not a jpeg", time.time()))
        pub.put_bytes(b"\x00\x01 not even rtp")
        pub.put_bytes(sender.frame(b"\x00\x05abcde", time.time()))  # RTP fine, metadata garbage
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not (len(reports) >= 6 and stats and
                                                   stats[-1].rejected.get("bad-rtp", 0) >= 1):
            time.sleep(0.1)
    good = {r.capture_id: r for r in reports if r.ok}
    assert set(good) == {0, 1, 2, 3}
    for cid, r in good.items():
        assert r.uav == 2 and r.defects, r
        d = r.defects[0]
        assert d.pos is not None and abs(d.pos[1] - 5.0) < 1e-6  # on the wall 5 m ahead
        assert 1000 * (r.stamp_report - r.stamp_capture) < 5000
    broken = [r for r in reports if not r.ok]
    assert any(r.capture_id == 99 and "decode" in r.error for r in broken)
    assert any("metadata" in r.error for r in broken)
    last = stats[-1]
    assert last.rejected["bad-rtp"] >= 1 and last.rejected["bad-image"] >= 1 and last.rejected["bad-meta"] >= 1
    assert last.metrics["uav2.cam0.delivered"] >= 6
    assert svc.alive()
