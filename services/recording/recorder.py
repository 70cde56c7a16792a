"""The mission log's writer: the one record of a mission, an MCAP file streamed as the mission goes.

Design notes: docs/recording.md (services/recording/recorder.py).
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from pathlib import Path

from pydantic import BaseModel

from protocol import keys
from protocol.budget import LIMITS, Budget
from protocol.bus import Bus, Reply, Ring
from protocol.links import COMMAND, LinkClass
from protocol.messages import ErrorReply, Message
from protocol.rtp import SeenFrames
from services.recording.record import ITEM_MODELS, MissionRecord
from services.recording.witness import FrameWitness, SurfaceCheck

from .mcap_log import McapLog, is_imagery

QUEUE_SAMPLES = 20_000  # small messages waiting for the disk (~20 s of a 12-UAV fleet's, a few MB)
QUEUE_FRAMES = 256  # imagery frames waiting for the disk (640x480 JPEGs: ~15 MB); beyond either, the oldest drop
FINISH_GRACE_S = 0.5
#: the ground station's own entries: record list -> channel (the header and footer have their own)
GROUND_TOPICS = {"commands": "/skynet/record/commands", "faults": "/skynet/record/faults",
                 "incidents": "/skynet/record/incidents", "events": "/skynet/record/events"}
HEADER_TOPIC = "/skynet/record/header"
FOOTER_TOPIC = "/skynet/record/footer"
#: the record's fields in the header; the footer has every field that is not a list of items
HEADER_FIELDS = {"fleet", "scenario", "speed", "started", "method", "transport"}


class MissionLogWriter:
    """Writes one mission's log to ``path``: the bus's samples (with ``bus``) and the ground station's entries.

    Thread-safe: every write goes through the writer's own lock; :meth:`add` never blocks on the disk."""

    def __init__(self, bus: Bus | None, path: str | Path, log=None, queue: int = QUEUE_SAMPLES,
                 frames: int = QUEUE_FRAMES, surface_check: SurfaceCheck | None = None):
        self.log = log
        self.mlog = McapLog(path)
        self.counts: Counter[str] = Counter()
        self.cpu_s = 0.0  # thread CPU time spent writing (the recording overhead)
        self.failed: str | None = None  # what went wrong writing, once it did
        self._lock = threading.Lock()  # one writer at a time; readers sort by log time (MCAP's index)
        self._ring = Ring(queue, self._write, name="recorder")
        self._frames = Ring(frames, self._write, name="recorder-frames")
        self._closed = threading.Event()
        self._budgets = {topic: Budget(limit) for topic, limit in LIMITS.items()}
        self._budget_lock = threading.Lock()  # Zenoh may call back from several threads
        self._frames_seen = SeenFrames()
        #: the capture frames logged, by RTP source, sequence number and digest: what the verdict checks the
        #: detector's reports against (services.gcs.evidence)
        self.witness = FrameWitness(surface_check=surface_check)
        if bus is not None:
            bus.subscribe_raw(keys.fleet_all(bus.fleet), self._on_sample)
            # capture frames lost on the way come again from the cameras' caches; this subscription only adds
            # frames not logged yet (its sequence tracking follows a source id any sender may claim)
            bus.subscribe_raw(keys.camera(bus.fleet, "*"), self._on_sample, recover=True)

    @property
    def path(self) -> Path:
        return self.mlog.path

    @property
    def dropped(self) -> int:
        return self._ring.dropped + self._frames.dropped

    # -- the bus
    def _on_sample(self, sample) -> None:
        if self._closed.is_set():
            return
        key, now = str(sample.key_expr), time.time()
        data = sample.payload.to_bytes()
        try:
            topic = keys.parse(key).topic
            if topic == "camera" and not self._first_time(key, data[:12]):
                return
            budget = self._budgets.get(topic)
        except keys.KeyError_:
            with self._budget_lock:
                self.counts["unknown-key"] += 1
            return
        if budget is not None:
            with self._budget_lock:
                if budget.admit(key, len(data), now) is not None:
                    self.counts["over-budget"] += 1
                    return
        if topic == "camera":
            self.witness.add_sample(key, data)
        self.sample(key, data, now)

    def _first_time(self, key: str, header: bytes) -> bool:
        """Whether a capture frame is new on ``key`` (by its RTP SSRC and sequence number, RFC 3550 5.1)."""
        with self._budget_lock:
            return self._frames_seen.first(key, int.from_bytes(header[8:12], "big"), int.from_bytes(header[2:4], "big"))

    def sample(self, key: str, data: bytes, rx: float) -> None:
        """Log one bus sample (its bytes as they came, its receive time), through the rings."""
        frame = is_imagery(key)
        (self._frames if frame else self._ring).push(("sample", key, data, rx, frame))

    def log_request(self, key: str, msg: Message, t_sent: float, reply: Reply, t_answer: float) -> None:
        """Log a request the ground station sent (a command, a plan request) and its answer or failure."""
        if self._closed.is_set():
            return
        answer = reply.message if reply.ok and reply.message is not None else \
            ErrorReply(code="no-ack" if not reply.ok else "empty", reason=(reply.error or "no answer")[:500])
        self._ring.push(("request", key, msg, t_sent, answer, t_answer))

    # -- the ground station's entries
    def begin(self, record: MissionRecord) -> None:
        """The record's header (fleet, scenario, speed, start), written at once."""
        doc = record.model_dump_json(include=HEADER_FIELDS)
        self._write(("json", HEADER_TOPIC, "skynet.record.Header", MissionRecord.model_json_schema, doc, record.started))

    def add(self, kind: str, item: BaseModel, t: float | None = None) -> None:
        """Log one entry of the ground station's own (``kind``: a key of :data:`GROUND_TOPICS`)."""
        if self._closed.is_set():
            return
        cls = type(item)
        self._ring.push(("json", GROUND_TOPICS[kind], f"skynet.record.{cls.__name__}", cls.model_json_schema,
                         item.model_dump_json(), time.time() if t is None else t))

    def _write(self, item: tuple) -> None:
        t0 = time.thread_time()
        with self._lock:
            if self.failed is not None or self.mlog.closed:
                self.counts["not-written"] += 1
                return
            try:
                if item[0] == "request":
                    _, key, msg, t_sent, answer, t_answer = item
                    self.mlog.write_message(key, msg, t_sent, kind="query")
                    self.mlog.write_message(key, answer, t_answer, kind="reply")
                    self.counts["requests"] += 1
                elif item[0] == "json":
                    _, topic, name, schema, doc, t = item
                    self.mlog.write_json(topic, name, schema, doc, t)
                    self.counts["ground"] += 1
                else:
                    self.counts[self.mlog.write_sample(*item[1:])] += 1
            except (OSError, ValueError) as exc:
                self._fail(exc)
            self.cpu_s += time.thread_time() - t0

    def _fail(self, exc: Exception) -> None:
        """The first write error (caller holds the lock): said once; nothing more is written."""
        self.failed = (f"writing the mission log {self.path} failed ({exc}); it keeps what was written before; "
                       "the rest is kept in memory only (bounded) and goes into the report")
        if self.log:
            self.log.error("%s. The mission goes on.", self.failed)

    # -- the end
    def finish(self, record: MissionRecord) -> None:
        """Write the footer (``record``'s fields that are not lists of items: plan, phases, verdict, counters),
        the writer's counts, and close the file. Lists are not touched, so no lock of the caller's is needed."""
        # a sample the ground station's callback has just taken may not have reached ours yet (Zenoh
        # calls the two subscribers one after the other): give it a moment before closing the log
        time.sleep(FINISH_GRACE_S)
        self._closed.set()
        self._ring.close(timeout=60.0)
        self._frames.close(timeout=60.0)
        if self.dropped and self.failed is None:
            record.recording_errors.append(f"{self.dropped} samples did not reach the mission log {self.path} "
                                           "(its queue was full)")
        footer = record.model_dump_json(exclude=set(ITEM_MODELS) | HEADER_FIELDS)
        self._write(("json", FOOTER_TOPIC, "skynet.record.Footer", MissionRecord.model_json_schema, footer, time.time()))
        self.close()
        if self.log:
            self.log.info("mission recorded to %s: %d messages, %d dropped", self.path, self.mlog.messages,
                          self.dropped)

    def close(self) -> None:
        """Close the file (without a footer: an interrupted run, read back with what it has)."""
        self._closed.set()
        self._ring.close(timeout=60.0)
        self._frames.close(timeout=60.0)
        with self._lock:
            try:
                if not self.mlog.closed:
                    self.mlog.metadata("skynet.recorder", {"dropped": self.dropped, "cpu_s": round(self.cpu_s, 3),
                                                           **self.counts})
                self.mlog.close()
            except (OSError, ValueError) as exc:
                if self.failed is None:
                    self._fail(exc)


class RecordingBus:
    """The ground station's bus with its requests logged: every :meth:`request` (the commands and
    their acknowledgements, the plan request and the plan) goes to the writer as a query and a
    reply on the request's key. Everything else is the wrapped :class:`~protocol.bus.Bus`."""

    def __init__(self, bus: Bus, writer: MissionLogWriter):
        self._bus, self._writer = bus, writer

    def __getattr__(self, name: str):
        return getattr(self._bus, name)

    def request_all(self, key: str, msg: Message, expect=None, timeout: float = 2.0, settle_s: float = 10.0,
                    link: LinkClass = COMMAND, **kw) -> list[Reply]:
        """:meth:`~protocol.bus.Bus.request_all`, every answer logged as received (a signed plan in its envelope)."""
        t_sent = time.time()
        replies = self._bus.request_all(key, msg, expect=expect, timeout=timeout, settle_s=settle_s, link=link, **kw)
        for reply in replies or [Reply(False, None, "no answer")]:
            self._writer.log_request(key, msg, t_sent, reply, t_sent + reply.elapsed_s)
        return replies

    def request(self, key: str, msg: Message, expect=None, timeout: float = 2.0, link: LinkClass = COMMAND) -> Reply:
        t_sent = time.time()
        reply = self._bus.request(key, msg, expect=expect, timeout=timeout, link=link)
        self._writer.log_request(key, msg, t_sent, reply, time.time())
        return reply
