"""The detector RCU service: every UAV's imagery in, one defect report per frame out.

Design notes: docs/detector.md (services/detector/service.py).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections import Counter

from protocol import binding, codec, keys
from protocol.budget import for_topic
from protocol.bus import Bus, Ring, config_from_args, setup_logging, stop_event_on_signals
from protocol.cliconfig import add_options, from_namespace
from protocol.imagery import split_payload
from protocol.jitter import Frame, JitterBuffers
from protocol.links import COMMAND, TELEMETRY
from protocol.messages import DefectReport, LinkStats
from protocol.readiness import notify_ready
from protocol.rtp import RtpError, SeenFrames, parse_ssrc, unpack_frame
from protocol.stages import LOG_PREFIX, StageTimes

from .config import QUEUE_FRAMES, DetectorConfig
from .detect import METHODS
from .frames import save_frame
from .partition import MAX_UAV, Partition
from .pool import DetectorPool, WorkerCrashed
from .recovery import RecoveryTracker

#: cameras per UAV the detector keeps a jitter buffer for (SSRC ``0x534BUUCC`` with CC below this):
#: the capture camera is 0, the preview camera 1 (edge.camera_service); any other SSRC is rejected, so a
#: sender cannot make the detector keep an unbounded number of buffers.
MAX_CAMERAS = 4


def frame_source(key: str, ssrc: int) -> tuple[int, int] | None:
    """``(uav, camera)`` of a frame on ``key`` (:func:`protocol.binding.frame_source`), None also for a camera
    beyond :data:`MAX_CAMERAS`."""
    src = binding.frame_source(key, ssrc)
    return None if src is None or src[1] >= MAX_CAMERAS else src


class DetectorService:
    """Binds the pipeline to the bus; see docs/detector.md."""

    def __init__(self, bus: Bus, method: str = "it+r", workers: int = 2, queue: int = QUEUE_FRAMES,
                 playout_delay_s: float = 0.05, log=None, recover: bool = True, save_frames: str | None = None,
                 partition: Partition = Partition(), max_uav: int = MAX_UAV, context: str = "spawn",
                 max_pixels: int | None = None):
        if method not in METHODS:
            raise ValueError(f"unknown method {method!r}; choose from {sorted(METHODS)}")
        self.bus, self.method, self.log = bus, method, log
        self.save_frames = save_frames  # folder for copies of the analysed captures (posed photos)
        self.counts: Counter[str] = Counter()
        self.latency_ms: list[float] = []
        self.analysed: Counter[int] = Counter()  # SSRC -> frames analysed (reports published)
        self.times = StageTimes()  # shutter -> arrival -> queue -> worker -> published (protocol.stages)
        # late frames too: out of order, but captures all the same (coverage)
        self._jb = JitterBuffers(capacity=64, playout_delay_s=playout_delay_s, release_late=True)
        self._lock = threading.Lock()
        self.partition, self.name = partition, partition.name
        # detection in worker processes; one Ring thread per process keeps at most `workers` frames in flight
        self.pool = DetectorPool(workers, context, max_pixels)
        self.pool.warm(method=method)
        self.work = Ring(queue, self._process, name=self.name, workers=workers)
        self.pub = bus.publisher(keys.defects(bus.fleet), COMMAND)
        self.stats_pub = bus.publisher(keys.rcu_stats(bus.fleet, self.name), TELEMETRY)
        self.recovery = RecoveryTracker() if recover else None  # None: recovery off
        # per-camera budget (protocol.budget), charged after the RTP header and SSRC check: frames of a
        # foreign SSRC on a camera's key are rejected without using up that camera's budget
        self._budget = for_topic("camera")
        self._seen = SeenFrames()  # frames taken, so that one the two subscriptions both deliver is taken once
        for cams in partition.camera_keys(bus.fleet, max_uav):  # the wildcard, or this partition's UAVs
            bus.subscribe_raw(cams, self._on_frame)
            if recover:
                # frames lost on a lossy link come again from the cameras' caches; this subscription only adds
                # frames the live one did not deliver (its sequence tracking follows a source id any sender
                # may claim, so it must not be the only path)
                bus.subscribe_raw(cams, self._on_recovered, recover=True)
        bus.token(keys.rcu_alive(bus.fleet, self.name))
        self._t0 = time.time()

    def _on_frame(self, sample, recovered: bool = False) -> None:
        now = time.time()
        data = sample.payload.to_bytes()
        try:
            header, payload = unpack_frame(data)
        except RtpError as exc:
            if not recovered:  # counted once, on the live path
                self.counts["bad-rtp"] += 1
                if self.counts["bad-rtp"] == 1 and self.log:
                    self.log.warning("dropping a sample that is not an RTP frame: %s", exc)
            return
        if frame_source(str(sample.key_expr), header.ssrc) is None:  # bodies bound to keys
            if not recovered:
                self.counts["bad-ssrc"] += 1
                if self.counts["bad-ssrc"] == 1 and self.log:
                    self.log.warning("dropping a frame with SSRC %#010x on %s: not that UAV's camera (further "
                                     "ones are only counted)", header.ssrc, sample.key_expr)
            return
        with self._lock:
            if self.recovery is not None and len(payload):  # an empty payload: an announce frame, not a capture
                (self.recovery.delivered if recovered else self.recovery.live)(header.ssrc, header.sequence, now)
            if not self._seen.first(str(sample.key_expr), header.ssrc, header.sequence):
                return
            over = self._budget.admit(f"{sample.key_expr}#{header.ssrc:08x}", len(data), now)
        if over is not None:
            self.counts[over] += 1
            if self.counts[over] == 1 and self.log:
                self.log.warning("%s: frames over the camera budget (%s); further ones are only counted",
                                 sample.key_expr, over)
            return
        if len(payload) == 0:  # a camera's announce frame (edge.camera_service.CameraLink.announce)
            self.counts["announce"] += 1
            return
        self.counts["frames"] += 1
        with self._lock:
            before = self._jb[header.ssrc].late_released if header.ssrc in self._jb else 0
            ready = self._jb.push(header, payload, now)
            if self._jb[header.ssrc].late_released > before:
                self.counts["late-analysed"] += 1
        for f in ready:
            self.work.push(f)

    def _on_recovered(self, sample) -> None:
        """The recovering path (recovery on): frames the live path has not delivered."""
        self._on_frame(sample, recovered=True)

    def poll(self) -> None:
        """Release frames whose wait for a missing predecessor is over."""
        with self._lock:
            now = time.time()
            ready = self._jb.pop_due(now)
            if self.recovery is not None:
                self.recovery.settle(now)
        for f in ready:
            self.work.push(f)

    def _process(self, frame: Frame) -> None:
        started = time.time()
        try:
            meta, image = split_payload(frame.payload)
        except codec.CodecError as exc:
            self.counts["bad-meta"] += 1
            uav, _ = parse_ssrc(frame.ssrc)  # checked on arrival (frame_source)
            if uav:
                self.pub.put(DefectReport(uav=uav, capture_id=0, stamp_capture=0.0, stamp_report=time.time(),
                                          method=self.method, ok=False, error=f"bad metadata: {exc}"[:500]))
            return
        if meta.uav != parse_ssrc(frame.ssrc)[0]:  # the metadata must name the camera's own UAV
            self.counts[binding.MISMATCH] += 1
            return
        try:  # in a worker process, with the evidence the ground station counts a capture on (pool.analyse_frame)
            report = self.pool.analyse(meta, image, self.method, frame.ssrc, frame.sequence)
        except WorkerCrashed as exc:
            self.counts["worker-crashed"] += 1
            report = DefectReport(uav=meta.uav, capture_id=meta.capture_id, stamp_capture=meta.stamp,
                                  stamp_report=time.time(), method=self.method, ok=False, error=str(exc))
        else:
            done = time.time()
            with self._lock:
                self.times.add("shutter-to-arrival", frame.arrival_s - meta.stamp)
                self.times.add("queue", started - frame.arrival_s)  # the playout hold and the queue
                self.times.add("worker", done - started)  # to the worker process and back: decode, detect, map
        with self._lock:
            self.analysed[frame.ssrc] += 1
        if self.save_frames and report.ok:
            save_frame(self.save_frames, meta, image)
        if not report.ok:
            self.counts["bad-image"] += 1
            if self.log:
                self.log.warning("uav %d capture %d: %s", meta.uav, meta.capture_id, report.error)
        else:
            self.counts["reports"] += 1
            self.latency_ms.append(1000 * (report.stamp_report - report.stamp_capture))
            del self.latency_ms[:-1000]
        self.pub.put(report)
        if report.ok:
            with self._lock:
                self.times.add("published", time.time() - meta.stamp)

    def stats(self) -> LinkStats:
        metrics: dict[str, float] = {}
        with self._lock:
            for ssrc in self._jb.sources:
                st = self._jb[ssrc].stats()
                try:
                    uav, cam = parse_ssrc(ssrc)
                except ValueError:  # never pushed (frame_source), but stats must not end the service
                    continue
                p = f"uav{uav}.cam{cam}"
                metrics.update({f"{p}.received": st.received, f"{p}.delivered": st.delivered, f"{p}.lost": st.lost,
                                f"{p}.late": st.late, f"{p}.duplicated": st.duplicated,
                                f"{p}.reordered": st.reordered, f"{p}.jitter_ms": 1000 * st.jitter_s,
                                f"{p}.fraction_lost": st.fraction_lost,
                                f"{p}.recovered": self.recovery.recovered[ssrc] if self.recovery else 0,
                                f"{p}.analysed": self.analysed[ssrc]})
        metrics["imagery.recovery"] = int(self.recovery is not None)
        # frames never received, from each camera's own sequence numbers (RFC 3550 6.4.1's cumulative loss),
        # not from the recovery's count, whose sequence tracking follows a source id any sender may claim
        with self._lock:
            metrics["imagery.unrecovered"] = sum(max(0, self._jb[s].stats().cumulative_lost) for s in self._jb.sources)
        metrics["queue.dropped"] = self.work.dropped
        metrics["queue.processed"] = self.work.processed
        metrics["pool.workers"] = self.pool.workers
        metrics["pool.crashes"] = self.pool.crashes
        with self._lock:
            metrics.update(self.times.metrics())
        counts = dict(self.counts)
        return LinkStats(source=self.name, stamp=time.time(), uptime_s=time.time() - self._t0,
                         rejected={**{k: v for k, v in counts.items() if k.startswith("bad")},
                                   **{k: v for k, v in counts.items() if k.startswith("budget")}},
                         metrics={**metrics, **{f"count.{k}": v for k, v in counts.items()}})

    def close(self) -> None:
        with self._lock:
            rest = self._jb.flush()
            if self.recovery is not None:
                self.recovery.settle(float("inf"))
        for f in rest:
            self.work.push(f)
        self.work.close(timeout=10.0)
        self.pool.close()


def build_parser() -> argparse.ArgumentParser:
    """``skynet detector``'s command line: the options of :class:`DetectorConfig`."""
    return add_options(argparse.ArgumentParser(prog="skynet detector", description=__doc__.split("\n\n")[0]),
                       DetectorConfig)


def main(argv: list[str] | None = None) -> int:
    """``skynet detector``: parse the command line, then :func:`run` the service."""
    parser = build_parser()
    return run(from_namespace(DetectorConfig, parser.parse_args(argv), parser))


def run(args: DetectorConfig) -> int:
    """The detector RCU from its configuration, until SIGINT/SIGTERM."""
    name = args.partition.name
    log = setup_logging(name)
    if args.method == "learned":  # a bad model file: one line naming it, before the bus and the workers start
        from .learned import ModelError, warm_up

        try:  # the model file and the runtime ($SKYNET_DETECTOR_RUNTIME) on a small frame
            log.info("learned detector runtime: %s", warm_up(shapes=((16, 24),)))
        except ModelError as exc:
            print(f"skynet detector: {exc}", file=sys.stderr)
            return 2
    stop = stop_event_on_signals()
    with Bus(config_from_args(args, role="detector"), fleet=args.fleet, name=name) as bus:
        svc = DetectorService(bus, args.method, args.workers, args.queue, args.playout_delay, log,
                              recover=not args.no_recovery, save_frames=args.save_frames,
                              partition=args.partition, max_uav=args.max_uav, context=args.start_method,
                              max_pixels=int(args.detect_max_mp * 1e6) if args.detect_max_mp > 0 else None)
        log.info("detector up: %s, partition %s, method %s, %d worker processes, recovery %s", name,
                 args.partition, args.method, args.workers, "off" if args.no_recovery else "on")
        notify_ready("detector", name)
        next_stats = time.monotonic() + 1.0
        while not stop.wait(0.01):
            try:
                svc.poll()
                if time.monotonic() >= next_stats:
                    next_stats += 1.0
                    svc.stats_pub.put(svc.stats())
            except Exception:  # nothing a sender can do may end the service: counted, logged once
                svc.counts["loop-error"] += 1
                if svc.counts["loop-error"] == 1:
                    log.exception("detector main loop pass failed (further ones are only counted)")
        svc.close()
        svc.stats_pub.put(svc.stats())
        log.info("%s %s %s", LOG_PREFIX, name, json.dumps(svc.times.summary()))
        log.info("shutting down: %s", dict(svc.counts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
