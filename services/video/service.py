"""``skynet video``: every UAV's camera as standard RTP over UDP, with an SDP file per stream.

Design notes: docs/operator-view.md (services/video/service.py).
"""

from __future__ import annotations

import argparse
import os
import threading
from collections import Counter
from functools import partial
from pathlib import Path

from protocol import binding, keys
from protocol.bus import Bus, Ring, setup_logging, stop_event_on_signals
from protocol.cliconfig import add_options, from_namespace
from protocol.imagery import unpack_image
from protocol.readiness import notify_ready
from protocol.rtp import ssrc_for

from .config import VideoConfig
from .sdp import sdp
from .stream import VideoStream

QUEUE_PICTURES = 2  # per stream: a live view drops the oldest picture rather than fall behind


class VideoService:
    """Binds :class:`~services.video.stream.VideoStream` per UAV and kind to the bus."""

    def __init__(self, bus: Bus, codec: str = "h264", host: str = "127.0.0.1", port: int = 5600,
                 capture_port: int | None = None, sdp_dir: str | Path = "sdp", log=None):
        self.bus, self.codec, self.host, self.log = bus, codec, host, log
        self.ports = {"preview": int(port)}
        if capture_port is not None:
            self.ports["capture"] = int(capture_port)
        self.sdp_dir = Path(sdp_dir)
        self.sdp_dir.mkdir(parents=True, exist_ok=True)
        self.streams: dict[tuple[int, str], tuple[VideoStream, Ring]] = {}
        self.counts: Counter[str] = Counter()
        self._lock = threading.Lock()
        bus.subscribe_raw(keys.preview(bus.fleet, "*"), lambda s: self._on_frame(s, "preview"))
        if capture_port is not None:
            bus.subscribe_raw(keys.camera(bus.fleet, "*"), lambda s: self._on_frame(s, "capture"))

    def port_of(self, uav: int, kind: str) -> int:
        port = self.ports[kind] + 2 * (uav - 1)
        if not 0 < port < 65536:
            raise ValueError(f"UAV {uav}'s {kind} port {port} is out of range")
        return port

    def sdp_path(self, uav: int, kind: str) -> Path:
        return self.sdp_dir / f"uav{uav}-{kind}.sdp"

    def stream(self, uav: int, kind: str) -> tuple[VideoStream, Ring]:
        """The stream of one UAV's preview or captures, created (and its SDP written) on first use."""
        with self._lock:
            if (uav, kind) not in self.streams:
                port = self.port_of(uav, kind)
                vs = VideoStream(self.codec, self.host, port, ssrc_for(uav, 0 if kind == "capture" else 1))
                ring = Ring(QUEUE_PICTURES, partial(self._send_job, vs), name=f"video-uav{uav}-{kind}")
                path = self.sdp_path(uav, kind)
                part = path.with_name(path.name + ".part")  # complete or absent: a player never reads half a file
                part.write_text(sdp(self.codec, self.host, port, f"SkyNet UAV {uav} {kind}"))
                os.replace(part, path)
                self.streams[(uav, kind)] = (vs, ring)
                if self.log:
                    self.log.info("UAV %d %s: %s RTP to %s:%d, %s", uav, kind, self.codec, self.host, port,
                                  self.sdp_path(uav, kind))
            return self.streams[(uav, kind)]

    def _on_frame(self, sample, kind: str) -> None:
        try:
            header, meta, jpeg = unpack_image(sample.payload.to_bytes())
        except ValueError:
            self.counts["bad-frame"] += 1  # the announce frame (empty payload) lands here too
            return
        if meta.encoding != "jpeg" or len(jpeg) == 0:
            self.counts["not-jpeg"] += 1
            return
        if not binding.matches(str(sample.key_expr), meta.uav):  # a camera speaks only for its own UAV
            self.counts[binding.MISMATCH] += 1
            return
        try:
            _, ring = self.stream(meta.uav, kind)
        except ValueError:  # the UAV's port beyond 65535 (a high --port and a large UAV id)
            self.counts["bad-port"] += 1
            return
        self.counts[f"in-{kind}"] += 1
        ring.push((bytes(jpeg), meta.stamp))

    def _send_job(self, vs: VideoStream, job: tuple[bytes, float]) -> None:
        self._send(vs, *job)

    def _send(self, vs: VideoStream, jpeg: bytes, stamp: float) -> None:
        try:
            vs.send(jpeg, stamp)
            self.counts["sent"] += 1
        except (ValueError, OSError) as exc:
            self.counts["send-error"] += 1
            if self.counts["send-error"] == 1 and self.log:
                self.log.warning("a picture was not sent: %s", exc)

    def close(self) -> None:
        for vs, ring in list(self.streams.values()):
            ring.close()
            vs.close()


def build_parser() -> argparse.ArgumentParser:
    """``skynet video``'s command line: the options of :class:`VideoConfig`."""
    return add_options(argparse.ArgumentParser(prog="skynet video", description=__doc__.split("\n\n")[0]), VideoConfig)


def main(argv: list[str] | None = None) -> int:
    """``skynet video``: parse the command line, then :func:`run` the service."""
    parser = build_parser()
    return run(from_namespace(VideoConfig, parser.parse_args(argv), parser), argv)


def run(args: VideoConfig, argv: list[str] | None = None) -> int:
    """The video service from its configuration (``argv``: whether ``--fleet`` was given), until SIGINT/SIGTERM."""
    from services.attach import open_bus

    log = setup_logging("video")
    stop = stop_event_on_signals()
    with open_bus(args, "video", argv) as bus:
        svc = VideoService(bus, args.codec, args.host, args.port, args.capture_port if args.capture else None,
                           args.sdp_dir, log)
        for uav in range(1, args.uavs + 1):
            for kind in svc.ports:
                svc.stream(uav, kind)
        log.info("video up: %s to %s, preview from port %d, SDP in %s", args.codec, args.host, args.port, args.sdp_dir)
        notify_ready("video")
        while not stop.wait(0.2):
            pass
        svc.close()
        log.info("shutting down: %s", dict(svc.counts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
