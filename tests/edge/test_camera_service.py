"""The edge camera's bus binding: capture frames with or without a recovery cache, and the
live preview stream (small, low-rate, plain best-effort, on its own key) -- over a real gateway."""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import pytest

from edge.camera_service import PREVIEW_CAMERA, capture_link, make_camera
from edge.config import IMAGERY_CACHE_FRAMES, PREVIEW_SIZE, EdgeConfig
from edge.vehicle.driver import CaptureEvent
from protocol import keys
from protocol.bus import Bus, BusConfig
from protocol.cliconfig import parse
from protocol.imagecodec import decode_image
from protocol.imagery import split_payload
from protocol.links import IMAGERY, IMAGERY_RELIABLE
from protocol.rtp import parse_ssrc, unpack_frame
from tests.conftest import wait_until

FLEET = "test"
log = logging.getLogger("test-runtime")


def _args(**kw) -> EdgeConfig:
    return EdgeConfig(uav=3, **kw)


def _facing_the_wall(cam) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """A position 5 m in front of the middle of the scenario's wall, and the attitude looking at it."""
    s = cam.surface
    pos = s.center + 5.0 * s.normal
    yaw = math.atan2(-s.normal[1], -s.normal[0])
    return tuple(map(float, pos)), (0.0, 0.0, yaw)


def _decode(sample) -> tuple[int, int, object, np.ndarray]:
    header, payload = unpack_frame(sample.payload.to_bytes())
    meta, jpeg = split_payload(payload)
    uav, camera = parse_ssrc(header.ssrc)
    return uav, camera, meta, decode_image(jpeg, grey=True)


def test_preview_is_small_rate_limited_best_effort_and_apart_from_captures(gateway):
    got_cam, got_preview = [], []
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "ground") as ground, Bus(cfg, FLEET, "uav3") as edge:
        ground.subscribe_raw(keys.camera(FLEET, "*"), got_cam.append, recover=True)  # as the detector does
        ground.subscribe_raw(keys.preview(FLEET, "*"), got_preview.append)
        cam = make_camera(_args(preview_hz=5.0), edge, log)
        try:
            assert cam.cache == IMAGERY_CACHE_FRAMES and cam.pub.matching() is None  # the recovery cache
            assert cam.preview_stream is not None
            assert cam.preview_stream.pub.matching() is not None  # a plain publisher: never a cache
            assert wait_until(lambda: cam.preview_stream.pub.matching(), 10)
            pos, att = _facing_the_wall(cam)
            # the control loop offers the pose at 50 Hz for 1.2 s (wall clock): 5 Hz lets 6 or 7 through
            t0 = time.time()
            queued = sum(cam.preview(pos, att, 0.02 * i, t0 + 0.02 * i) for i in range(60))
            assert queued == 6
            assert wait_until(lambda: len(got_preview) >= 1, 10)
            assert wait_until(lambda: len(got_cam) == 1, 10)  # the announce (live, or from the cache)
            cam.capture(CaptureEvent(capture_id=4, t=1.0, pos=pos, att=att), time.time())
            assert wait_until(lambda: len(got_cam) == 2, 10)
        finally:
            cam.close()
    # the stream opens with an empty announce frame (so that a lost first capture is a gap), then the capture
    first, _ = unpack_frame(got_cam[0].payload.to_bytes())
    assert len(_) == 0 and not first.marker and parse_ssrc(first.ssrc) == (3, 0)
    uav, camera, meta, img = _decode(got_cam[1])
    assert unpack_frame(got_cam[1].payload.to_bytes())[0].sequence == (first.sequence + 1) & 0xFFFF
    assert (uav, camera, meta.capture_id, img.shape) == (3, 0, 4, (480, 640))
    assert 1 <= len(got_preview) <= 6  # offers that come faster than the worker renders replace each other
    for s in got_preview:
        uav, camera, meta, img = _decode(s)
        assert (uav, camera) == (3, PREVIEW_CAMERA) and img.shape == PREVIEW_SIZE[::-1]
        assert meta.intrinsics.width == PREVIEW_SIZE[0] and 50 < img.mean() < 200  # the wall, not the sky


def test_preview_renders_only_while_somebody_watches(gateway):
    """No subscriber on the preview key: due offers are counted as unwatched and nothing is rendered;
    once a viewer subscribes (through the gateway), frames flow to it."""
    got = []
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "uav3") as edge:
        cam = make_camera(_args(preview_hz=5.0), edge, log)
        try:
            stream = cam.preview_stream
            pos, att = _facing_the_wall(cam)
            t0 = time.time()
            assert stream.pub.matching() is False
            assert sum(cam.preview(pos, att, 0.02 * i, t0 + 0.02 * i) for i in range(60)) == 0
            assert (stream.unwatched, stream.offered, stream.sent) == (6, 0, 0)
            with Bus(cfg, FLEET, "ground") as viewer:
                viewer.subscribe_raw(keys.preview(FLEET, "*"), got.append)
                assert wait_until(lambda: stream.pub.matching(), 10)
                t1 = t0 + 10.0
                assert sum(cam.preview(pos, att, 0.02 * i, t1 + 0.02 * i) for i in range(60)) == 6
                assert wait_until(lambda: len(got) >= 1, 10)
            assert stream.unwatched == 6 and stream.sent >= 1
        finally:
            cam.close()


def test_imagery_cache_zero_is_a_plain_publisher_and_preview_can_be_off(gateway):
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    with Bus(cfg, FLEET, "uav3") as edge:
        cam = make_camera(_args(imagery_cache=0, preview_hz=0.0), edge, log)
        try:
            assert cam.cache == 0 and cam.pub.matching() is not None  # no advanced publisher
            assert cam.preview_stream is None and not cam.preview((0, 0, 0), (0, 0, 0), 0.0, time.time())
        finally:
            cam.close()
    with pytest.raises(ValueError, match="imagery_cache"):
        _args(imagery_cache=-1)


def test_camera_options_are_typed_and_bad_values_are_refused(capsys):
    def edge(*argv: str) -> EdgeConfig:
        return parse(EdgeConfig, ["--uav", "3", *argv])

    assert edge("--imagery-cache", "0").imagery_cache == 0 and edge("--imagery-cache", "64").imagery_cache == 64
    assert edge("--preview-hz", "0").preview_hz == 0.0 and edge("--preview-hz", "2.5").preview_hz == 2.5
    assert edge("--frame-size", "4000x3000").frame_size == (4000, 3000)  # a pair of ints from the start
    assert edge().frame_size == (640, 480)
    bad = [("--imagery-cache", v) for v in ("-1", "x", "1.5")] + [("--preview-hz", v) for v in ("-1", "nan", "inf", "fast")]
    bad += [("--frame-size", v) for v in ("640", "0x480", "axb", "640x480x3", "99999x10")]
    for flag, value in bad:
        with pytest.raises(SystemExit) as exc:
            edge(f"{flag}={value}")
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert f"error: argument {flag}" in err[-1], err  # argparse's one line, no traceback


def test_capture_link_goes_reliable_for_frames_that_span_several_datagrams():
    assert capture_link("auto", (640, 480)) is IMAGERY  # one UDP datagram: the paper's RTP over UDP
    assert capture_link("auto", (4000, 3000)) is IMAGERY_RELIABLE  # the paper's 12 MP GoPro frames
    assert capture_link("best-effort", (4000, 3000)) is IMAGERY
    assert capture_link("reliable", (640, 480)) is IMAGERY_RELIABLE
    assert IMAGERY_RELIABLE.name == IMAGERY.name and IMAGERY_RELIABLE.reliable
    with pytest.raises(ValueError):
        capture_link("tcp", (640, 480))


def test_a_burst_of_12_mp_sized_frames_on_the_reliable_imagery_link_loses_none(gateway):
    """26 frames of 600 KB (a 12 MP JPEG, some ten UDP datagrams each) sent back to back
    through the gateway, as the camera publishes them (recovery cache on), to a plain subscriber."""
    got = []
    cfg = BusConfig(mode="client", connect=gateway, multilink=True)
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, 600_000, dtype=np.uint8).tobytes() for _ in range(26)]
    with Bus(cfg, FLEET, "ground") as ground, Bus(cfg, FLEET, "uav3") as edge:
        ground.subscribe_raw(keys.camera(FLEET, "*"), lambda s: got.append(s.payload.to_bytes()))
        pub = edge.publisher(keys.camera(FLEET, 3), IMAGERY_RELIABLE, cache=IMAGERY_CACHE_FRAMES)
        time.sleep(1.0)  # the subscription reaches the edge through the gateway
        for f in frames:
            pub.put_bytes(f)
        assert wait_until(lambda: len(got) >= len(frames), 30), f"{len(got)} of {len(frames)} frames arrived"
    assert got == frames


class _Recorder:
    def __init__(self, name: str) -> None:
        self.name, self.got = name, []

    def put_bytes(self, data: bytes) -> int:
        self.got.append(data)
        return len(data)

    def matching(self) -> bool:
        return True


def test_a_frame_encoded_while_the_edge_reopens_its_session_goes_out_on_the_new_one():
    """The edge reopens its session (a narrower ACL): a frame put while detached waits for the new session's
    publisher and goes out there, never on the closed one; with no session within the wait it is an error."""
    import threading

    from edge.camera_service import PublisherSlot

    made: list[_Recorder] = []

    def make(bus: str) -> _Recorder:
        made.append(_Recorder(bus))
        return made[-1]

    slot = PublisherSlot(make, "old", wait_s=5.0)  # type: ignore[arg-type]
    slot.put_bytes(b"1")
    slot.detach()
    assert slot.matching() is False  # the preview does not render for a session being reopened
    sender = threading.Thread(target=slot.put_bytes, args=(b"2",))
    sender.start()
    time.sleep(0.2)
    assert sender.is_alive()  # waiting for the reopened session
    slot.attach("new")  # type: ignore[arg-type]
    sender.join(2.0)
    assert [(r.name, r.got) for r in made] == [("old", [b"1"]), ("new", [b"2"])]
    slot.detach()
    short = PublisherSlot(make, "x", wait_s=0.05)  # type: ignore[arg-type]
    short.detach()
    with pytest.raises(ConnectionError, match="no session"):
        short.put_bytes(b"3")


class _Blocking(_Recorder):
    """A reliable put blocked by a subscriber that stopped reading; or one whose session closes under it."""

    def __init__(self, name: str, release, fail: bool = False) -> None:
        super().__init__(name)
        self.release, self.fail = release, fail

    def put_bytes(self, data: bytes) -> int:
        self.release.wait(5.0)
        if self.fail:
            raise RuntimeError("session closed")
        return super().put_bytes(data)


def test_a_blocked_put_never_holds_up_a_reopen_and_one_whose_session_closed_goes_to_the_next():
    import threading

    from edge.camera_service import PublisherSlot

    release = threading.Event()
    made: list[_Recorder] = []

    def make(bus: str) -> _Recorder:
        made.append(_Blocking(bus, release, fail=bus == "old") if bus == "old" else _Recorder(bus))
        return made[-1]

    slot = PublisherSlot(make, "old", wait_s=5.0)  # type: ignore[arg-type]
    sender = threading.Thread(target=slot.put_bytes, args=(b"1",))
    sender.start()
    time.sleep(0.1)
    t0 = time.monotonic()
    slot.detach()  # the put is still blocked: detach does not wait for it
    assert time.monotonic() - t0 < 0.5
    slot.attach("new")  # type: ignore[arg-type]
    release.set()  # the old session closes under the put: it goes out on the new one
    sender.join(2.0)
    assert not sender.is_alive() and made[1].got == [b"1"]
    slot.detach()
    waiting = threading.Thread(target=lambda: pytest.raises(ConnectionError, slot.put_bytes, b"2"))
    waiting.start()
    time.sleep(0.1)
    t0 = time.monotonic()
    slot.close()  # the edge stopping between two sessions: no 5 s wait per queued frame
    waiting.join(2.0)
    assert not waiting.is_alive() and time.monotonic() - t0 < 1.0
    with pytest.raises(ConnectionError, match="closed"):
        slot.put_bytes(b"3")
