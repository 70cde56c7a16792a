"""Wiring of the edge process: which driver, which camera, and the camera's bus binding.

The camera sends two imagery streams:

- **capture frames** on ``uav/<id>/camera``, one per capture point: what the detector analyses
  and what coverage counts. With ``imagery_cache`` N > 0 (default :data:`IMAGERY_CACHE_FRAMES`)
  the publisher keeps its last N frames and answers recovery queries (Zenoh's advanced
  publisher: the role RTP retransmission plays), so a frame lost on a lossy link is sent again;
  with 0 it is a plain best-effort publisher and a lost frame stays lost.
- **live preview frames** on ``uav/<id>/preview``: small (default 320x240, JPEG quality 60) at a
  low wall-clock rate (default 2 Hz, ``preview_hz`` 0 = off), always plain best-effort, never
  cached or recovered (a late preview frame is worth nothing), RTP camera index 1
  (:data:`PREVIEW_CAMERA`). Only the synthetic camera previews: a folder or video source is
  read by the captures alone, so that previews never take frames away from them.

Kept out of :mod:`edge.board` so that the board's logic stays a thin shell over the driver,
and so that the ground station can rebuild the very same synthetic surface (and so its ground
truth) from the scenario with :func:`synthetic_surface`.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import logging
import math
import threading
import time

import numpy as np

from protocol import keys
from protocol.bus import Bus
from protocol.imagery import pack_image
from protocol.links import IMAGERY, IMAGERY_RELIABLE, LinkClass
from protocol.messages import ImageMeta, Intrinsics
from protocol.rtp import RtpSender, ssrc_for
from protocol.scenario import Scenario, load_scenario
from protocol.stages import LOG_PREFIX, StageTimes

from .camera import CameraModel, CameraPose, FrameEncoder, SyntheticSource, encode_jpeg, make_source
from .surface import DEFAULT_PX_PER_M, SyntheticSurface
from .vehicle.driver import CaptureEvent, VehicleDriver
from .vehicle.quadrotor import DisturbanceParams
from .vehicle.sim import SimDriver, SimParams

#: frames each camera keeps for retransmission of frames lost on the way
IMAGERY_CACHE_FRAMES = 32
#: live preview defaults: rate (wall clock, Hz), frame size and JPEG quality
PREVIEW_HZ = 2.0
PREVIEW_SIZE = (320, 240)
PREVIEW_QUALITY = 60
#: RTP camera index of the preview stream (the capture stream is camera 0)
PREVIEW_CAMERA = 1
#: seed of the synthetic surface: one wall for the whole fleet, whatever the UAV
SURFACE_SEED = 2024
#: ``--capture-link auto``: capture frames larger than this (pixels) go on the reliable link
RELIABLE_CAPTURE_ABOVE_PX = 1_000_000
CAPTURE_LINKS = ("auto", "best-effort", "reliable")


def frame_size(text: str) -> str:
    """argparse type of ``--frame-size``: ``WxH``, each side 16..20000 pixels (returned as given)."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH (e.g. 640x480), got {text!r}") from None
    if not (16 <= w <= 20000 and 16 <= h <= 20000):
        raise argparse.ArgumentTypeError(f"frame size {text!r}: each side must be 16..20000 pixels")
    return text


def capture_link(choice: str, frame_size: tuple[int, int]) -> LinkClass:
    """The link class of capture frames: ``best-effort`` (UDP, the paper's RTP), ``reliable`` (TCP),
    or ``auto``: reliable above :data:`RELIABLE_CAPTURE_ABOVE_PX` pixels, whose JPEGs span several UDP
    datagrams (a 640x480 frame fits one; a 12 MP one lost 15-21 of 26 frames on a clean loopback)."""
    if choice not in CAPTURE_LINKS:
        raise ValueError(f"capture link must be one of {', '.join(CAPTURE_LINKS)}, got {choice!r}")
    if choice == "auto":
        choice = "reliable" if frame_size[0] * frame_size[1] > RELIABLE_CAPTURE_ABOVE_PX else "best-effort"
    return IMAGERY_RELIABLE if choice == "reliable" else IMAGERY


def cache_frames(text: str) -> int:
    """argparse type of ``--imagery-cache``: an int >= 0 (0 = no cache, capture frames not recoverable)."""
    try:
        n = int(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a number of frames >= 0, got {text!r}") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected a number of frames >= 0, got {text!r}")
    return n


def make_driver(args: argparse.Namespace, t0: float) -> VehicleDriver:
    if args.vehicle == "sim":
        wind = DisturbanceParams.moderate() if args.wind == "moderate" else DisturbanceParams()
        endurance = {} if getattr(args, "endurance", None) is None else {"endurance_s": args.endurance}
        return SimDriver(args.uav, params=SimParams(disturbance=wind, **endurance), home=args.home, t0=t0,
                         seed=args.seed if args.seed is not None else args.uav)
    from .vehicle.mavlink import MavlinkDriver  # needs the "mavlink" extra

    video = None
    if getattr(args, "mavlink_video", None) is not None:  # the preview as skynet video sends it (UAV 1: base)
        from .vehicle.mav_camera import VideoStreamSpec, stream_port

        video = VideoStreamSpec(stream_port(args.mavlink_video, args.uav), *PREVIEW_SIZE,
                                framerate=float(getattr(args, "preview_hz", PREVIEW_HZ)))
    from .vehicle.mavlink import MavlinkParams

    return MavlinkDriver(args.uav, args.mavlink, home=args.home, signing_key=getattr(args, "mavlink_key", None),
                         gcs_endpoint=getattr(args, "mavlink_gcs", None), gcs_video=video,
                         params=MavlinkParams(flight=getattr(args, "flight", "guided")))


def synthetic_surface(scenario: Scenario, px_per_m: float | None = None, seed: int = SURFACE_SEED):
    """The inspected wall of the scenario as a textured, cracked :class:`SyntheticSurface`."""
    if scenario.surface is None:
        raise ValueError(f"scenario {scenario.name!r} has no [surface] to image")
    corners = np.asarray(scenario.surface.corners, dtype=float)
    return SyntheticSurface.from_corners(corners, px_per_m=px_per_m or DEFAULT_PX_PER_M, seed=seed)


def camera_model(scenario: Scenario, frame_size: tuple[int, int]):
    """The scenario's camera delivering ``frame_size`` frames (the same field of view, fewer pixels)."""
    cam = scenario.camera
    return CameraModel(resolution=frame_size, sensor_mm=cam.sensor_mm, focal_mm=cam.focal_mm)


def camera_rotation(yaw: float) -> np.ndarray:
    """World-from-camera rotation of a gimbal-stabilised camera looking horizontally along ``yaw``.

    OpenCV camera axes: z forward (the optical axis), x right, y down.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    z = np.array([c, s, 0.0])
    x = np.array([s, -c, 0.0])
    y = np.array([0.0, 0.0, -1.0])
    return np.column_stack([x, y, z])


class CameraLink:
    """Capture -> frame -> JPEG (off the control loop) -> imagery sample on the bus.

    Parameters
    ----------
    cache : int
        Capture frames kept for recovery (>= 0; 0 = plain best-effort publisher, no recovery).
    preview : PreviewStream or None
        The live preview stream, fed by :meth:`preview`.
    """

    def __init__(self, bus: Bus, uav: int, source, model, surface=None, log: logging.Logger | None = None,
                 quality: int = 85, cache: int = IMAGERY_CACHE_FRAMES, preview: PreviewStream | None = None,
                 link: LinkClass = IMAGERY):
        if isinstance(cache, bool) or not isinstance(cache, int) or cache < 0:
            raise ValueError(f"imagery cache must be an int >= 0 (frames), got {cache!r}")
        self.bus, self.uav, self.source, self.model, self.surface, self.log = bus, uav, source, model, surface, log
        self.sender = RtpSender(ssrc_for(uav, 0))
        self.cache = cache
        # cache > 0 keeps the last frames for subscribers that ask (RTP retransmission-like recovery)
        self.pub = bus.publisher(keys.camera(bus.fleet, uav), link, cache=cache or None)
        self.encoder = FrameEncoder(self._publish, capacity=4, quality=quality)
        self.preview_stream = preview
        self.sent = 0
        # where a capture's time goes on the edge (protocol.stages; logged at close, bench/frame_path.py)
        self.times = StageTimes()
        self.announce()

    def announce(self) -> None:
        """Open the stream with an empty RTP frame (marker 0, no payload) before the first capture.

        Zenoh's recovering subscriber takes the first sample it sees from a publisher as the
        start of the stream: were the first *capture* lost, nothing would ask for it again. This
        frame is that first sample instead (a late subscriber gets it from the cache through the
        publisher's periodic heartbeat), so a lost first capture is a gap like any other and is
        recovered. The detector drops empty frames on arrival.
        """
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
        if self.preview_stream is not None:
            self.preview_stream.close()
        self.encoder.close()
        self.source.close()
        if self.log and self.times.stages:
            self.log.info("%s uav%d %s", LOG_PREFIX, self.uav, json.dumps(self.times.summary()))


class PreviewStream:
    """Low-rate live preview of one camera: render + encode on its own thread, plain best-effort.

    :meth:`offer` runs on the control loop: it only compares the wall clock with the next due
    time and, when due, leaves the pose in a one-slot mailbox (a newer pose replaces one not yet
    rendered, counted in :attr:`skipped`). The worker renders the frame with its own source (a
    :class:`~edge.camera.SyntheticSource` at the preview size), encodes it and publishes it on
    ``uav/<id>/preview`` without cache or recovery.

    A frame is rendered only while somebody watches: when Zenoh's matching status says no
    subscriber matches the preview key, a due offer is counted in :attr:`unwatched` and nothing is
    rendered (the render and encode were a quarter of an idle edge's CPU, spent on frames
    that nobody received).
    """

    def __init__(self, bus: Bus, uav: int, source, model, rate_hz: float = PREVIEW_HZ,
                 quality: int = PREVIEW_QUALITY, log: logging.Logger | None = None):
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"preview rate must be a finite number of Hz > 0, got {rate_hz!r}")
        if isinstance(quality, bool) or not isinstance(quality, int) or not 1 <= quality <= 100:
            raise ValueError(f"preview JPEG quality must be an int in 1..100, got {quality!r}")
        self.bus, self.uav, self.source, self.model, self.log = bus, uav, source, model, log
        self.period_s, self.quality = 1.0 / float(rate_hz), quality
        self.sender = RtpSender(ssrc_for(uav, PREVIEW_CAMERA))
        self.pub = bus.publisher(keys.preview(bus.fleet, uav), IMAGERY)  # never a cache: best-effort only
        self._next_due = 0.0
        self._slot: tuple | None = None
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


def release_freed_memory() -> None:
    """Hand the heap freed by start-up temporaries back to the system (glibc ``malloc_trim``):
    building the synthetic wall leaves about 24 MB free but held in every edge.
    A no-op where there is no glibc."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def make_camera(args: argparse.Namespace, bus: Bus, log: logging.Logger) -> CameraLink | None:
    if args.camera in ("", "none"):
        return None
    w, h = (int(v) for v in args.frame_size.lower().split("x"))
    scenario = load_scenario(args.scenario)
    model = camera_model(scenario, (w, h))
    surface = synthetic_surface(scenario) if args.camera == "synthetic" else None
    # the synthetic capture: no ground-truth mask (never sent) and a magnified view warped at the size the
    # texture fills, then resized (edge.camera.SyntheticSource, upsample: a 12 MP frame in ~8 ms, not 22-60)
    source = make_source(args.camera, surface=surface, camera=model, mask=False, upsample=True)
    cache = getattr(args, "imagery_cache", IMAGERY_CACHE_FRAMES)
    preview_hz = float(getattr(args, "preview_hz", PREVIEW_HZ) or 0.0)
    preview = None
    if preview_hz > 0 and surface is not None:
        small = camera_model(scenario, PREVIEW_SIZE)
        preview = PreviewStream(bus, args.uav, SyntheticSource(surface, small, mask=False), small, rate_hz=preview_hz,
                                log=log)
    elif preview_hz > 0:
        log.info("live preview off: only the synthetic camera previews (%s is read by the captures alone)",
                 args.camera)
    link = capture_link(getattr(args, "capture_link", "auto"), (w, h))
    release_freed_memory()
    return CameraLink(bus, args.uav, source, model, surface=surface, log=log, cache=cache, preview=preview, link=link)
