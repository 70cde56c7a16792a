"""The ground station's recorder: everything on the fleet's keys to an MCAP file, as it arrives.

One subscription on ``skynet/<fleet>/**`` (states, events, defect reports, statistics, the
heartbeat, capture and preview frames; ``@adv`` recovery traffic and liveliness tokens are not
samples of the key space and are not logged) hands each sample with its receive time to a
bounded drop-oldest ring (one for imagery frames, one for the rest); the rings' threads write it (:class:`~services.recording.mcap_log.McapLog`),
so the Zenoh callback never waits for the disk and memory stays bounded (ring + one chunk). What
the ring had to drop is counted and written in the file's ``skynet.recorder`` metadata. Before the
ring, each source is held to its topic's budget (:mod:`protocol.budget`, the subscribers' own limits,
charged by the key a sample came on): a flood of one key costs the recorder a look-up per sample,
not a log write, a decode and a compression on the ground station's GIL, and cannot evict the other
sources' samples from the ring. Samples on keys outside the key space (:func:`protocol.keys.parse`)
are not logged. Both are counted (``over-budget``, ``unknown-key``).

:class:`RecordingBus` adds the ground station's requests: Zenoh queries are seen by no
subscriber, so each command, acknowledgement, plan request and plan is logged where it is sent.

At the end, :meth:`Recorder.finish` freezes the ground station's record, writes what is not on
the bus (scenario, plan, commands and their acknowledgements, faults, phases, verdict) as the
last message with, for each received list, its first item and length, so that
:func:`services.recording.rebuild.rebuild` can make the same record from the file alone.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict

from protocol import keys
from protocol.budget import LIMITS, Budget
from protocol.bus import Bus, Reply, Ring
from protocol.links import COMMAND, LinkClass
from protocol.messages import ErrorReply, Message
from services.recording.record import MissionRecord

from .mcap_log import RECORD_TOPIC, McapLog, is_imagery

QUEUE_SAMPLES = 20_000  # small messages waiting for the disk (~20 s of a 12-UAV fleet's, a few MB)
QUEUE_FRAMES = 256  # imagery frames waiting for the disk (640x480 JPEGs: ~15 MB); beyond either, the oldest drop
FINISH_GRACE_S = 0.5
RECEIVED_LISTS = ("states", "defects", "events", "gateway_stats", "detector_stats")


class Window(BaseModel):
    """Where a received list of the record starts in the log, and how long it is."""

    model_config = ConfigDict(extra="forbid")
    first: dict[str, Any] | None = None
    n: int = 0


class MissionRecordSummary(BaseModel):
    """The record without its received lists (those are the log's messages), plus their windows."""

    model_config = ConfigDict(extra="forbid")
    record: MissionRecord
    windows: dict[str, Window]


class Recorder:
    def __init__(self, bus: Bus, path: str | Path, log=None, queue: int = QUEUE_SAMPLES, frames: int = QUEUE_FRAMES):
        self.log = log
        self.mlog = McapLog(path)
        self.counts: Counter[str] = Counter()
        self.cpu_s = 0.0  # thread CPU time spent writing (the recording overhead)
        self._lock = threading.Lock()  # one writer at a time; readers sort by log time (MCAP's index)
        self._ring = Ring(queue, self._write, name="recorder")
        self._frames = Ring(frames, self._write, name="recorder-frames")
        self._closed = threading.Event()
        self._budgets = {topic: Budget(limit) for topic, limit in LIMITS.items()}
        self._budget_lock = threading.Lock()  # Zenoh may call back from several threads
        bus.subscribe_raw(keys.fleet_all(bus.fleet), self._on_sample)

    @property
    def path(self) -> Path:
        return self.mlog.path

    @property
    def dropped(self) -> int:
        return self._ring.dropped + self._frames.dropped

    def _on_sample(self, sample) -> None:
        if self._closed.is_set():
            return
        key, now = str(sample.key_expr), time.time()
        try:
            budget = self._budgets.get(keys.parse(key).topic)
        except keys.KeyError_:
            with self._budget_lock:
                self.counts["unknown-key"] += 1
            return
        if budget is not None:
            with self._budget_lock:
                if budget.admit(key, len(sample.payload), now) is not None:
                    self.counts["over-budget"] += 1
                    return
        frame = is_imagery(key)
        (self._frames if frame else self._ring).push((key, sample.payload.to_bytes(), now, frame))

    def _write(self, item: tuple) -> None:
        t0 = time.thread_time()
        with self._lock:
            if item[0] == "request":
                _, key, msg, t_sent, answer, t_answer = item
                self.mlog.write_message(key, msg, t_sent, kind="query")
                self.mlog.write_message(key, answer, t_answer, kind="reply")
                self.counts["requests"] += 1
            else:
                self.counts[self.mlog.write_sample(*item)] += 1
            self.cpu_s += time.thread_time() - t0

    def log_request(self, key: str, msg: Message, t_sent: float, reply: Reply, t_answer: float) -> None:
        """Log a request the ground station sent (a command, a plan request) and its answer or failure."""
        if self._closed.is_set():
            return
        answer = reply.message if reply.ok and reply.message is not None else \
            ErrorReply(code="no-ack" if not reply.ok else "empty", reason=(reply.error or "no answer")[:500])
        self._ring.push(("request", key, msg, t_sent, answer, t_answer))

    def finish(self, record: MissionRecord, lock: threading.Lock | None = None) -> MissionRecord:
        """Freeze ``record`` (its lists as they are now, under ``lock``), log the summary, close the file.

        Returns the frozen record: the report written from it is the one the file rebuilds.
        """
        lock = lock or threading.Lock()
        with lock:
            frozen = record.model_copy(update={name: list(getattr(record, name)) for name in RECEIVED_LISTS})
        # a sample the ground station's callback has just taken may not have reached ours yet (Zenoh
        # calls the two subscribers one after the other): give it a moment before closing the log
        time.sleep(FINISH_GRACE_S)
        self._closed.set()
        self._ring.close(timeout=60.0)
        self._frames.close(timeout=60.0)
        windows = {}
        for name in RECEIVED_LISTS:
            items = getattr(frozen, name)
            windows[name] = Window(first=items[0].msg.model_dump(mode="json") if items else None, n=len(items))
        summary = MissionRecordSummary(record=frozen.model_copy(update={n: [] for n in RECEIVED_LISTS}),
                                       windows=windows)
        self.mlog.write_json(RECORD_TOPIC, "skynet.MissionRecordSummary", MissionRecordSummary.model_json_schema(),
                             summary.model_dump_json(), time.time())
        self.mlog.metadata("skynet.recorder", {"fleet": frozen.fleet, "dropped": self.dropped,
                                               "cpu_s": round(self.cpu_s, 3), **self.counts})
        self.mlog.close()
        if self.log:
            self.log.info("mission recorded to %s: %d messages, %d dropped", self.path, self.mlog.messages,
                          self.dropped)
        return frozen

    def close(self) -> None:
        """Close without a mission record (an interrupted run)."""
        self._closed.set()
        self._ring.close(timeout=60.0)
        self._frames.close(timeout=60.0)
        self.mlog.close()


class RecordingBus:
    """The ground station's bus with its requests logged: every :meth:`request` (the commands and
    their acknowledgements, the plan request and the plan) goes to the recorder as a query and a
    reply on the request's key. Everything else is the wrapped :class:`~protocol.bus.Bus`."""

    def __init__(self, bus: Bus, recorder: Recorder):
        self._bus, self._recorder = bus, recorder

    def __getattr__(self, name: str):
        return getattr(self._bus, name)

    def request_all(self, key: str, msg: Message, expect=None, timeout: float = 2.0, settle_s: float = 10.0,
                    link: LinkClass = COMMAND, **kw) -> list[Reply]:
        """:meth:`~protocol.bus.Bus.request_all`, every answer logged as received (a signed plan in its envelope)."""
        t_sent = time.time()
        replies = self._bus.request_all(key, msg, expect=expect, timeout=timeout, settle_s=settle_s, link=link, **kw)
        for reply in replies or [Reply(False, None, "no answer")]:
            self._recorder.log_request(key, msg, t_sent, reply, t_sent + reply.elapsed_s)
        return replies

    def request(self, key: str, msg: Message, expect=None, timeout: float = 2.0, link: LinkClass = COMMAND) -> Reply:
        t_sent = time.time()
        reply = self._bus.request(key, msg, expect=expect, timeout=timeout, link=link)
        self._recorder.log_request(key, msg, t_sent, reply, time.time())
        return reply
