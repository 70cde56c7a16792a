"""The ground station's recorder: everything on the fleet's keys to an MCAP file, as it arrives.

One subscription on ``skynet/<fleet>/**`` (states, events, defect reports, statistics, the
heartbeat, capture and preview frames; ``@adv`` recovery traffic and liveliness tokens are not
samples of the key space and are not logged) hands each sample with its receive time to a
bounded drop-oldest ring; the ring's thread writes it (:class:`~services.recording.mcap_log.McapLog`),
so the Zenoh callback never waits for the disk and memory stays bounded (ring + one chunk). What
the ring had to drop is counted and written in the file's ``skynet.recorder`` metadata.

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
from protocol.bus import Bus, Ring
from services.gcs.record import MissionRecord

from .mcap_log import RECORD_TOPIC, McapLog

QUEUE_SAMPLES = 20_000  # ~20 s of a 12-UAV fleet's traffic; beyond it the oldest samples drop (counted)
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
    def __init__(self, bus: Bus, path: str | Path, log=None, queue: int = QUEUE_SAMPLES):
        self.log = log
        self.mlog = McapLog(path)
        self.counts: Counter[str] = Counter()
        self.cpu_s = 0.0  # thread CPU time spent writing (the recording overhead)
        self._ring = Ring(queue, self._write, name="recorder")
        bus.subscribe_raw(keys.fleet_all(bus.fleet), self._on_sample)
        self._closed = threading.Event()

    @property
    def path(self) -> Path:
        return self.mlog.path

    def _on_sample(self, sample) -> None:
        if not self._closed.is_set():
            self._ring.push((str(sample.key_expr), sample.payload.to_bytes(), time.time()))

    def _write(self, item: tuple[str, bytes, float]) -> None:
        t0 = time.thread_time()
        self.counts[self.mlog.write_sample(*item)] += 1
        self.cpu_s += time.thread_time() - t0

    def finish(self, record: MissionRecord, lock: threading.Lock | None = None) -> MissionRecord:
        """Freeze ``record`` (its lists as they are now, under ``lock``), log the summary, close the file.

        Returns the frozen record: the report written from it is the one the file rebuilds.
        """
        lock = lock or threading.Lock()
        with lock:
            frozen = record.model_copy(update={name: list(getattr(record, name)) for name in RECEIVED_LISTS})
        self._closed.set()
        self._ring.close(timeout=60.0)
        windows = {}
        for name in RECEIVED_LISTS:
            items = getattr(frozen, name)
            windows[name] = Window(first=items[0].msg.model_dump(mode="json") if items else None, n=len(items))
        summary = MissionRecordSummary(record=frozen.model_copy(update={n: [] for n in RECEIVED_LISTS}),
                                       windows=windows)
        self.mlog.write_json(RECORD_TOPIC, "skynet.MissionRecordSummary", MissionRecordSummary.model_json_schema(),
                             summary.model_dump_json(), time.time())
        self.mlog.metadata("skynet.recorder", {"fleet": frozen.fleet, "dropped": self._ring.dropped,
                                               "cpu_s": round(self.cpu_s, 3), **self.counts})
        self.mlog.close()
        if self.log:
            self.log.info("mission recorded to %s: %d messages, %d dropped", self.path, self.mlog.messages,
                          self._ring.dropped)
        return frozen

    def close(self) -> None:
        """Close without a mission record (an interrupted run)."""
        self._closed.set()
        self._ring.close(timeout=60.0)
        self.mlog.close()
