"""The detector service end to end over the real bus: frames in, reports out, corrupt frames counted."""

import time

import cv2
import numpy as np
import pytest

from edge.world.surface import crack_image
from protocol import binding, keys
from protocol.bus import Bus, BusConfig
from protocol.imagery import pack_image
from protocol.links import IMAGERY, IMAGERY_RELIABLE
from protocol.messages import DefectReport, ImageMeta, Intrinsics, LinkStats
from protocol.rtp import RtpSender, ssrc_for
from tests.conftest import wait_until

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
    assert svc.wait_ready(30), "\n".join(svc.lines)
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
        # statistics are periodic, and a frame that does not decode is counted by its worker after the
        # report: wait for a period that counts all three rejections
        while time.monotonic() < deadline and not (len(reports) >= 6 and stats and all(
                stats[-1].rejected.get(k, 0) >= 1 for k in ("bad-rtp", "bad-image", "bad-meta"))
                and stats[-1].metrics.get("path.published.n", 0) >= 4):
            time.sleep(0.1)
    good = {r.capture_id: r for r in reports if r.ok}
    assert set(good) == {0, 1, 2, 3}
    for r in good.values():
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
    # where the frames' time went (protocol.stages): a sample per analysed frame in each stage
    assert last.metrics["path.worker.n"] >= 4 and last.metrics["path.queue.n"] >= 4
    assert last.metrics["path.worker.max_ms"] >= last.metrics["path.worker.p50_ms"] > 0
    assert svc.alive()


class CrackCamera:
    """A frame source (edge.world.camera.FrameSource) of synthetic cracked walls, one new image per grab."""

    def __init__(self, seed: int, size=(240, 320)):
        self.rng, self.size = np.random.default_rng(seed), size

    def grab(self, pose, t):
        from edge.world.camera import Frame

        grey, mask = crack_image(self.size, self.rng, n_cracks=2)
        return Frame(grey, t, pose, mask)

    def close(self):
        pass


N_FRAMES = 60
ONSET_S = 3.0  # the proxy passes everything before, so that the detector's UDP link opens


@pytest.mark.parametrize("recovery", [True, False], ids=["recovery-on", "recovery-off"])
def test_capture_frames_lost_on_the_detectors_udp_link(group, gateway, recovery):
    """with recovery on (camera cache + recovering subscriber) every capture frame lost on the
    detector's lossy UDP link still arrives and is counted ``recovered``; with it off (``--imagery-cache 0``,
    ``--no-recovery``) frames are lost for good. Real processes, a real lossy UDP proxy (seeded)."""
    from edge.camera_service import CameraLink
    from edge.geometry.optics import CameraModel
    from edge.vehicle.driver import CaptureEvent
    from protocol.bus import endpoint_address
    from services.netem.proxy import UdpProxy

    tcp, udp = gateway
    with UdpProxy(("127.0.0.1", 0), endpoint_address(udp), f"after {ONSET_S}s loss 25%", seed=11) as lossy:
        t_proxy = time.monotonic()
        via = [tcp, f"udp/127.0.0.1:{lossy.port}?rel=0"]
        svc = group.start("detector", ["detector", "--fleet", FLEET, "--multilink",
                                       *[a for e in via for a in ("--connect", e)],
                                       *([] if recovery else ["--no-recovery"])])
        assert svc.wait_ready(30), "\n".join(svc.lines)
        assert svc.wait_for("recovery " + ("on" if recovery else "off"), 1)
        reports: dict[int, DefectReport] = {}
        stats: list[LinkStats] = []
        with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uav2") as uav:
            uav.subscribe(keys.defects(FLEET), lambda m, s: reports.setdefault(m.capture_id, m), expect=DefectReport)
            uav.subscribe(keys.rcu_stats(FLEET, "detector"), lambda m, s: stats.append(m), expect=LinkStats)
            assert wait_until(lambda: uav.alive(keys.rcu_alive(FLEET, "detector")), 10)
            assert wait_until(lambda: lossy.stats()["down"]["sent_packets"] > 0, 10), lossy.stats()  # UDP link is up
            cam = CameraLink(uav, 2, CrackCamera(5), CameraModel(resolution=(320, 240)),
                             cache=32 if recovery else 0)
            time.sleep(max(0.5, ONSET_S + 0.3 - (time.monotonic() - t_proxy)))  # the loss has started
            for cid in range(N_FRAMES):
                cam.capture(CaptureEvent(capture_id=cid, t=0.1 * cid, pos=(10.0, 0.0, 20.0),
                                         att=(0.0, 0.0, np.pi / 2)), time.time())
                time.sleep(1 / 15)
            cam.close()

            def cam_metric(name):
                return stats[-1].metrics.get(f"uav2.cam0.{name}", 0) if stats else 0

            if recovery:
                assert wait_until(lambda: len(reports) == N_FRAMES and cam_metric("delivered") == N_FRAMES
                                  and cam_metric("recovered") > 0, 20), \
                    (len(reports), stats[-1].metrics if stats else None)
            else:
                wait_until(lambda: cam_metric("delivered") + cam_metric("lost") >= N_FRAMES - 5, 10)
                time.sleep(1.5)  # a last statistics period
                # statistics are periodic: on a loaded machine wait for a period that counts every frame reported
                wait_until(lambda: cam_metric("delivered") >= len(reports), 10)
            last = stats[-1].metrics
        dropped = lossy.stats()["down"]["dropped"]["loss"]
    assert dropped > 0  # the link really lost datagrams
    if recovery:
        assert sorted(reports) == list(range(N_FRAMES))  # full coverage
        assert last["uav2.cam0.delivered"] == N_FRAMES and last["uav2.cam0.lost"] == 0
        assert last["uav2.cam0.recovered"] > 0 and last["imagery.recovery"] == 1 and last["imagery.unrecovered"] == 0
    else:
        assert len(reports) < N_FRAMES and last["uav2.cam0.lost"] > 0
        assert last["uav2.cam0.recovered"] == 0 and last["imagery.recovery"] == 0
        assert last["imagery.unrecovered"] >= last["uav2.cam0.lost"] > 0
        assert last["uav2.cam0.delivered"] == len(reports)


def test_a_frame_late_for_playout_is_still_analysed(group, gateway):
    """A capture that arrives after the jitter buffer gave its number up is counted late, and still imaged."""
    svc = group.start("detector", ["detector", "--fleet", FLEET, "--multilink", "--no-recovery",
                                   *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    reports: dict[int, DefectReport] = {}
    stats: list[LinkStats] = []
    rng = np.random.default_rng(4)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uav") as uav:
        uav.subscribe(keys.defects(FLEET), lambda m, s: reports.setdefault(m.capture_id, m), expect=DefectReport)
        uav.subscribe(keys.rcu_stats(FLEET, "detector"), lambda m, s: stats.append(m), expect=LinkStats)
        assert wait_until(lambda: uav.alive(keys.rcu_alive(FLEET, "detector")), 10)
        time.sleep(0.5)
        pub = uav.publisher(keys.camera(FLEET, 4), IMAGERY)
        sender = RtpSender(ssrc_for(4))
        packets = []
        for cid in range(3):
            grey, _ = crack_image((240, 320), rng, n_cracks=2)
            packets.append(pack_image(sender, _meta(4, cid, 320, 240), cv2.imencode(".jpg", grey)[1].tobytes(),
                                      time.time()))
        pub.put_bytes(packets[0])
        pub.put_bytes(packets[2])  # 1 is missing: given up after the playout delay (50 ms)
        time.sleep(0.5)
        pub.put_bytes(packets[1])  # ... and comes late
        assert wait_until(lambda: len(reports) == 3 and stats and stats[-1].metrics.get("uav4.cam0.late") == 1, 15), \
            (sorted(reports), stats[-1].metrics if stats else None)
    m = stats[-1].metrics
    assert m["uav4.cam0.lost"] == 1 and m["uav4.cam0.delivered"] == 2 and m["count.late-analysed"] == 1
    assert all(r.ok for r in reports.values())


def test_hostile_frames_are_counted_and_the_detector_keeps_running(group, gateway):
    """a frame with a foreign SSRC (0x12345678) on a UAV's own camera key, random bytes that read
    as RTP version 2, and a frame with another UAV's SSRC used to end the detector (parse_ssrc in stats()).
    Now each is a counted rejection (``bad-ssrc``) and a good frame sent after them is still analysed."""
    svc = group.start("detector", ["detector", "--fleet", FLEET, "--multilink",
                                   *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    reports: list[DefectReport] = []
    stats: list[LinkStats] = []
    rng = np.random.default_rng(12)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uav") as uav:
        uav.subscribe(keys.defects(FLEET), lambda m, s: reports.append(m), expect=DefectReport)
        uav.subscribe(keys.rcu_stats(FLEET, "detector"), lambda m, s: stats.append(m), expect=LinkStats)
        assert wait_until(lambda: uav.alive(keys.rcu_alive(FLEET, "detector")), 10)
        time.sleep(0.5)
        pub = uav.publisher(keys.camera(FLEET, 2), IMAGERY)
        grey, _ = crack_image((240, 320), rng, n_cracks=1)
        jpeg = cv2.imencode(".jpg", grey)[1].tobytes()
        pub.put_bytes(pack_image(RtpSender(0x12345678), _meta(2, 7, 320, 240), jpeg, time.time()))
        pub.put_bytes(pack_image(RtpSender(ssrc_for(3)), _meta(3, 7, 320, 240), jpeg, time.time()))
        for _ in range(200):  # random bytes whose first byte says RTP version 2
            pub.put_bytes(bytes([0x80]) + rng.integers(0, 256, int(rng.integers(11, 200)), dtype=np.uint8).tobytes())
        time.sleep(1.5)  # a few stats passes over whatever reached the jitter buffers
        own = RtpSender(ssrc_for(2))
        # UAV 2's own camera, but metadata speaking for UAV 3 (bodies bound to keys)
        pub.put_bytes(pack_image(own, _meta(3, 9, 320, 240), jpeg, time.time()))
        pub.put_bytes(pack_image(own, _meta(2, 8, 320, 240), jpeg, time.time()))
        assert wait_until(lambda: any(r.ok and r.capture_id == 8 for r in reports), 20), reports
        assert wait_until(lambda: stats and stats[-1].rejected.get("bad-ssrc", 0) >= 2, 10), stats[-1:]
        assert wait_until(lambda: stats[-1].metrics.get(f"count.{binding.MISMATCH}", 0) >= 1, 10), stats[-1:]
    assert svc.alive(), "\n".join(svc.lines[-20:])
    assert not any(r.capture_id in (7, 9) or r.uav == 3 for r in reports)  # no forged frame was analysed
    assert stats[-1].metrics.get("count.loop-error", 0) == 0
    assert sum("SSRC" in line for line in svc.lines) == 1  # logged once


def test_two_partitioned_detectors_analyse_every_frame_of_four_uavs_exactly_once(group, gateway):
    """``--partition 0/2`` and ``1/2`` over the real bus; 4 UAVs' cameras send 5 captures each. Every
    capture is reported exactly once, by the instance that owns its UAV (the other is not even delivered it:
    its statistics never name that camera), and each instance has its own token and statistics key."""
    from collections import Counter

    uavs, per_uav = (1, 2, 3, 4), 5
    for k in (0, 1):
        svc = group.start(f"detector-{k}", ["detector", "--fleet", FLEET, "--multilink", "--partition", f"{k}/2",
                                            "--uavs", "8", *[a for e in gateway for a in ("--connect", e)]])
        assert svc.wait_ready(30), "\n".join(svc.lines)
    reports: list[DefectReport] = []
    stats: dict[str, LinkStats] = {}
    rng = np.random.default_rng(18)
    with Bus(BusConfig(mode="client", connect=gateway, multilink=True), FLEET, "uavs") as bus:
        bus.subscribe(keys.defects(FLEET), lambda m, s: reports.append(m), expect=DefectReport)
        bus.subscribe(keys.rcu_instances(FLEET, "detector", "stats"),
                      lambda m, s: stats.__setitem__(keys.parse(str(s.key_expr)).name, m), expect=LinkStats)
        assert wait_until(lambda: all(bus.alive(keys.rcu_alive(FLEET, f"detector-{k}")) for k in (0, 1)), 10)
        assert not bus.alive(keys.rcu_alive(FLEET, "detector"))
        time.sleep(0.5)
        # reliable: what is checked is the partition, not the loss of a best-effort datagram (one of 20 frames
        # went missing once in a two-worker CI run, a mission loading the other core)
        pubs = {u: bus.publisher(keys.camera(FLEET, u), IMAGERY_RELIABLE) for u in uavs}
        senders = {u: RtpSender(ssrc_for(u)) for u in uavs}
        for cid in range(per_uav):
            for u in uavs:  # every UAV at its capture point together
                grey, _ = crack_image((240, 320), rng, n_cracks=1)
                jpeg = cv2.imencode(".jpg", grey)[1].tobytes()
                pubs[u].put_bytes(pack_image(senders[u], _meta(u, cid, 320, 240), jpeg, time.time()))
            time.sleep(0.05)
        total = len(uavs) * per_uav
        assert wait_until(lambda: len(reports) >= total and set(stats) == {"detector-0", "detector-1"} and sum(
            st.metrics.get(f"uav{u}.cam0.analysed", 0) for st in stats.values() for u in uavs) == total, 30), \
            (len(reports), {n: {k: v for k, v in st.metrics.items() if k.endswith((".received", ".analysed", ".lost"))}
                            for n, st in stats.items()})
        time.sleep(1.0)  # a duplicate, if any, would arrive now
    seen = Counter((r.uav, r.capture_id) for r in reports)
    assert seen == Counter({(u, c): 1 for u in uavs for c in range(per_uav)})
    assert all(r.ok and r.frame is not None for r in reports)
    for k in (0, 1):
        m = stats[f"detector-{k}"].metrics
        assert stats[f"detector-{k}"].source == f"detector-{k}"
        for u in uavs:
            if u % 2 == k:
                assert m[f"uav{u}.cam0.analysed"] == per_uav and m[f"uav{u}.cam0.received"] == per_uav
            else:
                assert f"uav{u}.cam0.received" not in m  # never delivered to this instance
        assert m["pool.workers"] == 2 and m["pool.crashes"] == 0


def test_a_uav_claiming_anothers_publisher_id_cannot_keep_its_frames_from_the_detector(group, gateway):
    """Recovery tracks sequence numbers per source id, which any sender may claim: uav2 puts one sample on its
    own camera key under uav1's camera's id, far ahead in sequence, so that the recovering subscription drops
    uav1's next frames as already seen and reports about a million of them missed. The detector still analyses
    every one of them (the live subscription hands them over; recovery only adds frames the link lost), counts
    none as recovered and none as unrecovered."""
    import zenoh

    svc = group.start("detector", ["detector", "--fleet", FLEET, "--multilink",
                                   *[a for e in gateway for a in ("--connect", e)]])
    assert svc.wait_ready(30), "\n".join(svc.lines)
    reports: dict[int, DefectReport] = {}
    stats: list[LinkStats] = []
    rng = np.random.default_rng(5)
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "uav1") as uav1, Bus(cfg, FLEET, "uav2") as uav2:
        uav1.subscribe(keys.defects(FLEET), lambda m, s: reports.setdefault(m.capture_id, m), expect=DefectReport)
        uav1.subscribe(keys.rcu_stats(FLEET, "detector"), lambda m, s: stats.append(m), expect=LinkStats)
        assert wait_until(lambda: uav1.alive(keys.rcu_alive(FLEET, "detector")), 10)
        time.sleep(0.5)
        pub = uav1.publisher(keys.camera(FLEET, 1), IMAGERY, cache=16)
        sender = RtpSender(ssrc_for(1))
        frames = []
        for cid in range(8):
            grey, _ = crack_image((240, 320), rng, n_cracks=1)
            ok, jpeg = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 90])
            frames.append(pack_image(sender, _meta(1, cid, 320, 240), jpeg.tobytes(), time.time()))
        for f in frames[:3]:
            pub.put_bytes(f)
            time.sleep(0.1)
        assert wait_until(lambda: len(reports) == 3, 15), sorted(reports)
        uav2.session.put(keys.camera(FLEET, 2), b"forged", source_info=zenoh.SourceInfo(pub._pub.id, 1_000_000))
        time.sleep(1.0)
        for f in frames[3:]:
            pub.put_bytes(f)
            time.sleep(0.1)
        wait_until(lambda: len(reports) == 8 and stats and stats[-1].metrics.get("uav1.cam0.analysed", 0) == 8, 15)
        last = stats[-1].metrics if stats else {}
    assert sorted(reports) == list(range(8)), sorted(reports)
    assert last.get("uav1.cam0.recovered") == 0, last
    assert last.get("imagery.unrecovered") == 0, last  # not the million the claimed sequence number implies
