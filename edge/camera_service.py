"""The camera's bus binding on the edge: capture frames and the live preview, from the edge's config.

Design notes: docs/edge.md (edge/camera_service.py).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from protocol import keys
from protocol.bus import Bus, Publisher
from protocol.heap import release_freed_memory
from protocol.imagecodec import encode_jpeg
from protocol.imagery import pack_image
from protocol.links import IMAGERY, IMAGERY_RELIABLE, LinkClass
from protocol.messages import ImageMeta, Intrinsics
from protocol.rtp import RtpSender, ssrc_for
from protocol.scenario import load_scenario
from protocol.stages import LOG_PREFIX, StageTimes

from .camera import FrameEncoder, make_source
from .config import CAPTURE_LINKS, IMAGERY_CACHE_FRAMES, PREVIEW_HZ, PREVIEW_SIZE, EdgeConfig
from .geometry.camera import camera_model, camera_rotation
from .geometry.optics import CameraPose
from .vehicle.driver import CaptureEvent
from .world.camera import SyntheticSource
from .world.wall import synthetic_surface

#: live preview JPEG quality
PREVIEW_QUALITY = 60
#: RTP camera index of the preview stream (the capture stream is camera 0)
PREVIEW_CAMERA = 1
#: ``--capture-link auto``: capture frames larger than this (pixels) go on the reliable link
RELIABLE_CAPTURE_ABOVE_PX = 1_000_000


#: how long a frame waits for the session being reopened (edge.board) before it is counted as failed
REBIND_WAIT_S = 10.0


class PublisherSlot:
    """A stream's publisher that outlives its session: :meth:`detach` before the session closes, :meth:`attach`
    on the reopened one; a put in between waits for it (up to ``wait_s``), so no frame is sent on a closed
    session nor lost to a reopen that the edge makes to apply a narrower ACL. A put runs outside the slot's
    lock (a blocked reliable put never holds up :meth:`detach`); one that fails because the session closed
    under it is tried once more on the next one."""

    def __init__(self, make: Callable[[Bus], Publisher], bus: Bus, wait_s: float = REBIND_WAIT_S):
        self._make, self._wait_s = make, wait_s
        self._cond = threading.Condition()
        self._pub: Publisher | None = make(bus)
        self._closed = False

    @property
    def detached(self) -> bool:
        return self._pub is None

    def _current(self) -> Publisher:
        with self._cond:
            if not self._cond.wait_for(lambda: self._pub is not None or self._closed, self._wait_s) \
                    or self._pub is None:
                raise ConnectionError("the camera is closed" if self._closed else
                                      f"no session to publish on for {self._wait_s:g} s")
            return self._pub

    def put_bytes(self, data: bytes) -> int:
        """Put ``data`` on the current session's publisher; ConnectionError when none came within ``wait_s``
        or the slot was closed meanwhile."""
        pub = self._current()
        try:
            return pub.put_bytes(data)
        except Exception:
            if self._pub is pub:  # not a session closing under the put: the error is the put's own
                raise
        return self._current().put_bytes(data)

    def matching(self) -> bool | None:
        """:meth:`protocol.bus.Publisher.matching`; False while detached."""
        pub = self._pub
        return False if pub is None else pub.matching()

    def detach(self) -> None:
        with self._cond:
            self._pub = None

    def attach(self, bus: Bus) -> None:
        with self._cond:
            self._pub = self._make(bus)
            self._cond.notify_all()

    def close(self) -> None:
        """Puts waiting for a session (and later ones) fail at once."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


def capture_link(choice: str, frame_size: tuple[int, int]) -> LinkClass:
    """The link class of capture frames: ``best-effort`` (UDP, the paper's RTP), ``reliable`` (TCP),
    or ``auto``: reliable above :data:`RELIABLE_CAPTURE_ABOVE_PX` pixels, whose JPEGs span several UDP
    datagrams (a 640x480 frame fits one; a 12 MP one lost 15-21 of 26 frames on a clean loopback)."""
    if choice not in CAPTURE_LINKS:
        raise ValueError(f"capture link must be one of {', '.join(CAPTURE_LINKS)}, got {choice!r}")
    if choice == "auto":
        choice = "reliable" if frame_size[0] * frame_size[1] > RELIABLE_CAPTURE_ABOVE_PX else "best-effort"
    return IMAGERY_RELIABLE if choice == "reliable" else IMAGERY


class CameraLink:
    """Capture -> frame -> JPEG (off the control loop) -> imagery sample on the bus, keeping ``cache`` capture
    frames for recovery (0: a plain best-effort publisher) and feeding the ``preview`` stream if any."""

    def __init__(self, bus: Bus, uav: int, source, model, surface=None, log: logging.Logger | None = None,
                 quality: int = 85, cache: int = IMAGERY_CACHE_FRAMES, preview: PreviewStream | None = None,
                 link: LinkClass = IMAGERY):
        self.uav, self.source, self.model, self.surface, self.log = uav, source, model, surface, log
        self.sender = RtpSender(ssrc_for(uav, 0))
        self.cache = cache
        # cache > 0 keeps the last frames for subscribers that ask (RTP retransmission-like recovery)
        self.pub = PublisherSlot(lambda b: b.publisher(keys.camera(b.fleet, uav), link, cache=cache or None), bus)
        self.encoder = FrameEncoder(self._publish, capacity=4, quality=quality)
        self.preview_stream = preview
        self.sent = 0
        # where a capture's time goes on the edge (protocol.stages; logged at close, bench/frame_path.py)
        self.times = StageTimes()
        self.announce()

    def detach(self) -> None:
        """Before the edge closes the session: frames encoded from now wait for :meth:`attach`."""
        self.pub.detach()
        if self.preview_stream is not None:
            self.preview_stream.pub.detach()

    def attach(self, bus: Bus) -> None:
        """Publish on the edge's reopened session (the RTP stream and its sequence numbers go on)."""
        self.pub.attach(bus)
        if self.preview_stream is not None:
            self.preview_stream.pub.attach(bus)

    def announce(self) -> None:
        """Open the stream with an empty RTP frame (marker 0, no payload) before the first capture."""
        self.pub.put_bytes(self.sender.frame(b"", time.time(), marker=False))

    def range_to_surface(self, pos: np.ndarray, axis: np.ndarray) -> float | None:
        """Distance along the optical axis to the wall (what a rangefinder would measure)."""
        if self.surface is None:
            return None
        n = self.surface.normal
        along = float(np.dot(axis, n))
        if along >= -1e-6:
            return None
        return float(np.dot(self.surface.origin - pos, n)) / along

    def intrinsics(self, width: int, height: int) -> Intrinsics:
        fx, fy, cx, cy = self.model.scaled(width, height).intrinsics()
        return Intrinsics(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)

    def capture(self, ev: CaptureEvent, stamp: float) -> None:
        R = camera_rotation(ev.att[2])
        pose = CameraPose(position=np.asarray(ev.pos, dtype=float), rotation=R)
        frame = self.source.grab(pose, ev.t)
        self.times.add("render", time.time() - stamp)
        if frame is None:
            if self.log:
                self.log.warning("capture %d: the camera gave no frame", ev.capture_id)
            return
        h, w = frame.image.shape[:2]
        rng = self.range_to_surface(pose.position, R[:, 2])
        meta = ImageMeta(uav=self.uav, capture_id=ev.capture_id, t=max(0.0, ev.t), stamp=stamp,
                         cam_pos=tuple(map(float, ev.pos)), cam_rot=tuple(map(float, R.ravel())),
                         intrinsics=self.intrinsics(w, h), range_m=rng if rng and rng <= 1000 else None)
        self.encoder.submit(frame.image, (meta, time.time()))

    def _publish(self, tag: tuple[ImageMeta, float], jpeg: bytes) -> None:
        meta, submitted = tag
        t0 = time.time()
        self.times.add("encode", t0 - submitted)  # the encoder's queue and the encode
        self.pub.put_bytes(pack_image(self.sender, meta, jpeg, meta.stamp))
        t1 = time.time()
        self.times.add("publish", t1 - t0)
        self.times.add("shutter-to-sent", t1 - meta.stamp)
        self.sent += 1

    def preview(self, pos, att, t: float, now_wall: float) -> bool:
        """Offer the current pose to the live preview (cheap; call it every control tick).

        Returns True when a preview frame was queued (the stream's rate limit decides).
        """
        if self.preview_stream is None:
            return False
        return self.preview_stream.offer(pos, att, t, now_wall)

    def close(self) -> None:
        if self.pub.detached:  # stopped between two sessions: what is queued cannot go out, so do not wait for it
            self.pub.close()
        if self.preview_stream is not None:
            self.preview_stream.pub.close()
            self.preview_stream.close()
        self.encoder.close()
        self.pub.close()
        self.source.close()
        if self.log and self.times.stages:
            self.log.info("%s uav%d %s", LOG_PREFIX, self.uav, json.dumps(self.times.summary()))


class PreviewStream:
    """Low-rate live preview of one camera: render + encode on its own thread, plain best-effort, only while a
    subscriber matches (docs/edge.md, edge/camera_service.py)."""

    def __init__(self, bus: Bus, uav: int, source, model, rate_hz: float = PREVIEW_HZ,
                 quality: int = PREVIEW_QUALITY, log: logging.Logger | None = None):
        self.uav, self.source, self.model, self.log = uav, source, model, log
        self.period_s, self.quality = 1.0 / float(rate_hz), quality
        self.sender = RtpSender(ssrc_for(uav, PREVIEW_CAMERA))
        # never a cache: best-effort only
        self.pub = PublisherSlot(lambda b: b.publisher(keys.preview(b.fleet, uav), IMAGERY), bus)
        self._next_due = 0.0
        self._slot: tuple[tuple[float, ...], tuple[float, ...], float, float] | None = None
        self._cond = threading.Condition()
        self._closed = False
        self.offered = self.sent = self.skipped = self.failed = self.unwatched = 0
        self._thread = threading.Thread(target=self._run, name=f"preview-uav{uav}", daemon=True)
        self._thread.start()

    def offer(self, pos, att, t: float, now_wall: float) -> bool:
        if now_wall < self._next_due or self._closed:
            return False
        # a steady grid of due times; the first offer, or one after a stall, restarts the grid from now
        late = now_wall - self._next_due >= self.period_s
        self._next_due = (now_wall if late else self._next_due) + self.period_s
        if self.pub.matching() is False:
            self.unwatched += 1
            return False
        with self._cond:
            if self._slot is not None:
                self.skipped += 1
            self._slot = (tuple(map(float, pos)), tuple(map(float, att)), float(t), float(now_wall))
            self.offered += 1
            self._cond.notify()
        return True

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._slot is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                job, self._slot = self._slot, None
            if job is None:
                continue
            try:
                self._send(*job)
            except Exception:  # a preview never takes the edge down
                self.failed += 1
                if self.failed == 1 and self.log:
                    self.log.exception("preview frame failed")

    def _send(self, pos, att, t: float, stamp: float) -> None:
        R = camera_rotation(att[2])
        frame = self.source.grab(CameraPose(position=np.asarray(pos, dtype=float), rotation=R), t)
        h, w = frame.image.shape[:2]
        fx, fy, cx, cy = self.model.scaled(w, h).intrinsics()
        meta = ImageMeta(uav=self.uav, capture_id=0, t=max(0.0, t), stamp=stamp, cam_pos=pos,
                         cam_rot=tuple(map(float, R.ravel())),
                         intrinsics=Intrinsics(width=w, height=h, fx=fx, fy=fy, cx=cx, cy=cy))
        self.pub.put_bytes(pack_image(self.sender, meta, encode_jpeg(frame.image, self.quality), stamp))
        self.sent += 1

    def close(self, timeout: float = 2.0) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout)


def make_camera(config: EdgeConfig, bus: Bus, log: logging.Logger) -> CameraLink | None:
    """The camera of ``--camera`` (none for ``""``/``none``) bound to the bus, with its live preview."""
    if config.camera in ("", "none"):
        return None
    scenario = load_scenario(config.scenario)
    model = camera_model(scenario, config.frame_size)
    surface = synthetic_surface(scenario) if config.camera == "synthetic" else None
    # the synthetic capture: no ground-truth mask (never sent) and a magnified view warped at the size the
    # texture fills, then resized (edge.world.camera.SyntheticSource, upsample: a 12 MP frame in ~8 ms, not 22-60)
    source = make_source(config.camera, surface=surface, camera=model, mask=False, upsample=True)
    preview = None
    if config.preview_hz > 0 and surface is not None:
        small = camera_model(scenario, PREVIEW_SIZE)
        preview = PreviewStream(bus, config.uav, SyntheticSource(surface, small, mask=False), small,
                                rate_hz=config.preview_hz, log=log)
    elif config.preview_hz > 0:
        log.info("live preview off: only the synthetic camera previews (%s is read by the captures alone)",
                 config.camera)
    link = capture_link(config.capture_link, config.frame_size)
    release_freed_memory()
    return CameraLink(bus, config.uav, source, model, surface=surface, log=log, cache=config.imagery_cache,
                      preview=preview, link=link)
