"""What the ground station records during a mission: the input of the mission report.

Plain pydantic data (no bus code), serialisable to JSON with ``record.model_dump_json()`` and
back with ``MissionRecord.model_validate_json``, so a report can be re-made from a saved run.
Every ``rx`` field is the wall-clock UNIX time the ground station received the item.

Streamed and bounded. :class:`Recorder` is how the ground station records: every item
goes, as it arrives, to an append-only journal (``record.jsonl``: one JSON object a line, written
by a thread of its own and flushed at least every :data:`FLUSH_S`, so a crash or a full disk keeps
what came before), and into the in-memory :class:`MissionRecord` only up to a cap per kind
(:data:`CAPS`; states beyond it are decimated, other kinds stop being kept in memory; the journal
has them all). :func:`read_journal` reads the journal back, line by line, into a record bounded the same
way (:func:`keep`): the report is computed from it (:mod:`services.gcs.journal`); a cut or corrupted line
is counted and skipped. :func:`check_output_folder` refuses to start a mission whose folder is not writable or
has less than :data:`MIN_FREE_BYTES` free. A write error during the mission never stops it: the
recorder stops writing, says once where the data went (the journal up to the failure, the rest in
memory), and the record carries the error (``recording_errors``).
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from protocol import codec
from protocol.messages import DefectReport, Event, LinkStats, MissionPlan, VehicleState
from protocol.scenario import Scenario

#: A UAV reached its goal when, at the end of its trajectory (progress 1, before landing), it is
#: this close to its last planned waypoint, m. The mission's verdict and the report both use it.
GOAL_RADIUS_M = 2.0


class Received(BaseModel):
    model_config = ConfigDict(extra="forbid")
    rx: float


class StateRx(Received):
    msg: VehicleState


class DefectRx(Received):
    msg: DefectReport


class EventRx(Received):
    msg: Event


class StatsRx(Received):
    msg: LinkStats


class CommandRecord(BaseModel):
    """One command as the ground station sent it: acknowledged or not, after how many tries."""

    model_config = ConfigDict(extra="forbid")
    uav: int
    kind: str
    cmd_id: int
    ok: bool
    accepted: bool
    reason: str = ""
    attempts: int = 1
    elapsed_s: float = Field(description="from the first send to the final answer, s")
    ack_s: list[float] = Field(default=[], description="round-trip time of each answered try, s")


class FaultRecord(BaseModel):
    """One fault injected into the run (or ended), as the injector told the ground station.

    ``action`` is one of kill, restart, cut, restore, partition, heal (services.orchestration.faults), or what the
    launcher's supervisor did: supervisor-restart, start-failed (not injected); ``at`` is the
    wall-clock UNIX time it happened.
    """

    model_config = ConfigDict(extra="forbid")
    at: float
    action: str
    target: str
    text: str = ""


#: What an :class:`Incident` can say (the ground station's view of a fault and what it did about it).
INCIDENT_KINDS = (
    "token-gone",     # a UAV's liveliness token went away (crash: at once; silent loss: after its lease)
    "token-back",     # ... and came back
    "uav-lost",       # gone longer than the grace while the ground station's own link was up: not waited for
    "uav-back",       # a lost UAV's token is back (restarted, link restored)
    "link-down",      # the ground station's own session lost the gateway
    "link-up",        # ... and found it again
    "hold-seen",      # a UAV holds mid-mission without a ground-station command (its failsafe)
    "resume",         # the ground station resumed it (acknowledged and accepted)
    "resume-failed",  # the resume was not acknowledged or was refused
)


class Incident(BaseModel):
    """Something the ground station noticed about a fault, or did about one."""

    model_config = ConfigDict(extra="forbid")
    at: float = Field(description="wall-clock UNIX time")
    kind: str = Field(description="one of INCIDENT_KINDS")
    uav: int | None = None
    text: str = ""


class GroundTruthDefect(BaseModel):
    """A crack really on the synthetic surface (what the system should find)."""

    model_config = ConfigDict(extra="forbid")
    id: int
    pos: tuple[float, float, float] = Field(description="centroid, ENU m")
    uv: tuple[float, float] = Field(description="centroid in surface coordinates, m")
    bbox_uv: tuple[float, float, float, float] = Field(description="u0, v0, u1, v1 in surface coordinates, m")
    area_m2: float = 0.0


class MissionRecord(BaseModel):
    model_config = ConfigDict(extra="forbid")
    fleet: str
    scenario: Scenario | None = Field(default=None, description="the mission's scenario (None: not known)")
    speed: float = Field(description="simulation speed factor of the run")
    started: float = Field(description="wall-clock UNIX time the mission started")
    ended: float = 0.0
    plan: MissionPlan | None = None
    plan_request_s: float = 0.0
    states: list[StateRx] = []
    defects: list[DefectRx] = []
    events: list[EventRx] = []
    gateway_stats: list[StatsRx] = []
    detector_stats: list[StatsRx] = []
    commands: list[CommandRecord] = []
    faults: list[FaultRecord] = Field(default=[], description="faults injected during the run (services.orchestration.faults)")
    incidents: list[Incident] = Field(default=[], description="what the ground station saw of faults and did")
    heartbeats_sent: int = 0
    ground_truth: list[GroundTruthDefect] = []
    surface_corners: list[tuple[float, float, float]] = []
    success: bool = False
    failures: list[str] = []
    phases: dict[str, float] = Field(default={}, description="phase name -> wall time it began")
    recording_errors: list[str] = Field(default=[], description="what went wrong writing the record, and where "
                                        "the data went")
    not_kept: dict[str, int] = Field(default={}, description="items of each kind the in-memory record did not keep "
                                     "(over its cap, Recorder); the journal has them")
    imagery: dict[int, dict[str, int | None]] = Field(default={}, description="per UAV: frames sent, received, "
                                                      "analysed, reported (services.gcs.evidence.ledger)")
    rejected: dict[str, int] = Field(default={}, description="samples the ground station refused, 'key|kind' -> "
                                     "count: undecodable, or over a source's budget (protocol.budget)")
    report_input: str = Field(default="", description="what the report was computed from: the journal read back, "
                              "or the in-memory record and why (services.gcs.journal.report_record)")


# ============================================================================ streamed, bounded recording
#: free space the output folder must have when a mission starts, bytes (a 1-hour mission's journal at
#: the budgets' rates is well under this; protocol.budget)
MIN_FREE_BYTES = 64 * 1024 * 1024
#: items of each kind the in-memory record keeps (the journal keeps all). States beyond the cap are
#: decimated (every other one dropped, so the whole flight stays, at half the rate); the others stop.
CAPS: dict[str, int] = {"states": 200_000, "defects": 20_000, "events": 2_000, "gateway_stats": 10_000,
                        "detector_stats": 10_000, "commands": 20_000, "faults": 1_000, "incidents": 10_000}
#: the journal is flushed at least this often, s
FLUSH_S = 0.5
#: items waiting for the journal's writer; beyond, new ones are not journalled (counted)
JOURNAL_QUEUE = 20_000
#: the kinds a journal line may carry, and their item models
ITEM_MODELS: dict[str, type[BaseModel]] = {
    "states": StateRx, "defects": DefectRx, "events": EventRx, "gateway_stats": StatsRx, "detector_stats": StatsRx,
    "commands": CommandRecord, "faults": FaultRecord, "incidents": Incident,
}


class RecordingError(OSError):
    """The output folder cannot take the mission's record (not writable, not enough room)."""


def check_output_folder(folder: str | Path, min_free: int = MIN_FREE_BYTES) -> Path:
    """Create ``folder`` if needed and check it is a writable directory with ``min_free`` bytes free.

    Raises :class:`RecordingError` saying what is wrong (before any UAV takes off)."""
    out = Path(folder)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out, prefix=".write-check-") as fh:
            fh.write(b"x")
            fh.flush()
            os.fsync(fh.fileno())
        free = shutil.disk_usage(out).free
    except OSError as exc:
        raise RecordingError(f"the report folder {out} is not writable: {exc.strerror or exc}") from None
    if free < min_free:
        raise RecordingError(f"the report folder {out} has {free / 1e6:.1f} MB free, less than the "
                             f"{min_free / 1e6:.0f} MB a mission record needs")
    return out


def keep(record: MissionRecord, kind: str, item: BaseModel, caps: dict[str, int]) -> None:
    """Append ``item`` to ``record``'s list ``kind`` within its cap (:data:`CAPS`): over the cap, states are
    decimated (every other one dropped: the whole flight at half the rate) and other kinds are no longer
    kept; either way ``record.not_kept`` counts what was let go. The one bounding policy of the live record
    (:class:`Recorder`) and of the journal read back (:func:`read_journal`)."""
    items: list = getattr(record, kind)
    cap = caps.get(kind)
    if cap is None or len(items) < cap:
        items.append(item)
    elif kind == "states":
        before = len(items)
        del items[1::2]
        items.append(item)
        record.not_kept[kind] = record.not_kept.get(kind, 0) + before - len(items) + 1
    else:
        record.not_kept[kind] = record.not_kept.get(kind, 0) + 1


class Recorder:
    """Records into ``record`` (bounded, :data:`CAPS`) and streams every item to ``journal`` (a path, or
    None for memory only). Thread-safe; :meth:`add` never blocks on the disk."""

    def __init__(self, record: MissionRecord, journal: str | Path | None = None, log=None,
                 caps: dict[str, int] | None = None, queue_size: int = JOURNAL_QUEUE):
        self.record, self.log = record, log
        self.caps = {**CAPS, **(caps or {})}
        self.path = Path(journal) if journal is not None else None
        self.lines = 0  # journal lines written
        self.not_journalled = 0  # items the journal could not take (queue full, or after a write error)
        self.failed: str | None = None
        self._lock = threading.Lock()
        self._decimate: dict[str, int] = {}
        self._q: queue.Queue = queue.Queue(maxsize=queue_size)
        self._thread: threading.Thread | None = None
        self._fh = None
        if self.path is not None:
            self._fh = open(self.path, "a", encoding="utf-8")
            head = record.model_dump(mode="json", include={"fleet", "scenario", "speed", "started"})
            self._q.put(("header", json.dumps(head)))
            self._thread = threading.Thread(target=self._write, name="journal", daemon=True)
            self._thread.start()

    # -- recording
    def add(self, kind: str, item: BaseModel) -> None:
        """Append ``item`` to the record's list ``kind`` (within its cap) and to the journal."""
        with self._lock:
            keep(self.record, kind, item, self.caps)
        self._journal(kind, item)

    def _journal(self, kind: str, item: BaseModel) -> None:
        if self._thread is None or self.failed is not None:
            if self._thread is not None:
                self.not_journalled += 1
            return
        try:
            self._q.put_nowait((kind, item))
        except queue.Full:
            self.not_journalled += 1

    def _write(self) -> None:
        last_flush = time.monotonic()
        while True:
            try:
                kind, item = self._q.get(timeout=FLUSH_S)
            except queue.Empty:
                kind = None
            if kind == "end":
                self._flush(final=True, footer=item)
                return
            if self.failed is not None:
                continue  # drain: nothing more reaches the disk
            try:
                if kind == "header":
                    self._fh.write(json.dumps({"k": "header", "v": json.loads(item)}) + "\n")
                elif kind is not None:
                    self._fh.write('{"k":"%s","v":%s}\n' % (kind, item.model_dump_json()))
                if kind is not None:
                    self.lines += 1
                if kind is None or time.monotonic() - last_flush >= FLUSH_S:
                    self._fh.flush()
                    last_flush = time.monotonic()
            except (OSError, ValueError) as exc:
                self._fail(exc)

    def _flush(self, final: bool, footer: str | None) -> None:
        if self.failed is None:
            try:
                if footer is not None:
                    self._fh.write(footer + "\n")
                    self.lines += 1
                self._fh.flush()
                os.fsync(self._fh.fileno())
            except (OSError, ValueError) as exc:
                self._fail(exc)
        if final:
            try:
                self._fh.close()
            except OSError:
                pass  # what was buffered is lost with the disk; the failure is already said

    def _fail(self, exc: Exception) -> None:
        where = (f"{self.path} keeps the record up to the failure ({self.lines} lines); the rest is kept in "
                 f"memory only (bounded) and goes into the report")
        self.failed = f"writing the mission journal failed ({exc}); {where}"
        with self._lock:
            self.record.recording_errors.append(self.failed)
        if self.log:
            self.log.error("%s. The mission goes on.", self.failed)

    def close(self, timeout: float = 10.0) -> None:
        """Write the footer (everything that is not a list item: plan, verdict, ...), flush, fsync, close."""
        if self._thread is None:
            return
        lists = set(ITEM_MODELS)
        with self._lock:  # said before the footer, so that the record read back says it too
            if self.not_journalled and self.failed is None:
                self.record.recording_errors.append(f"{self.not_journalled} items did not reach the journal "
                                                    f"{self.path} (its queue was full)")
            footer = json.dumps({"k": "footer", "v": self.record.model_dump(mode="json", exclude=lists)})
        self._q.put(("end", footer))
        self._thread.join(timeout)
        if self._thread.is_alive():
            self._fail(TimeoutError(f"the journal's writer did not finish within {timeout:.0f} s"))
        self._thread = None


@dataclass
class JournalReadout:
    """What :func:`read_journal` found in a journal besides the record."""

    lines: int = 0  # lines read
    items: int = 0  # list items read (kept or let go by the caps)
    damaged: int = 0  # lines that were not a journal line (cut, corrupted, an unknown kind or item): skipped
    first_damaged: int | None = None  # the line number (from 1) of the first of them
    footer: bool = False  # the footer was read (the mission ended and closed its journal)

    def notes(self, path: str | Path) -> list[str]:
        """What the record read back must say about its journal (none for a whole, undamaged one)."""
        out = []
        if self.damaged:
            out.append(f"{path}: {self.damaged} damaged line(s) skipped (the first is line {self.first_damaged})")
        if not self.footer:
            out.append(f"{path} has no footer (the run did not close its journal): the plan, the verdict and "
                       "the counters are not in it")
        return out


def read_journal(path: str | Path, caps: dict[str, int] | None = None) -> tuple[MissionRecord, JournalReadout]:
    """The :class:`MissionRecord` of a journal written by :class:`Recorder`, read line by line into a record
    bounded like the live one (``caps``, default :data:`CAPS`, through :func:`keep`), and what was found.

    A line that is not a journal line (cut short by a crash or a full disk, corrupted, an item that does
    not validate) is counted and skipped; a missing footer leaves the header's fields and the items. The
    record's ``recording_errors`` say both (:meth:`JournalReadout.notes`) and ``not_kept`` counts what the
    caps let go while reading. ValueError if the file has no header."""
    caps = CAPS if caps is None else caps
    out = JournalReadout()
    head: dict[str, Any] | None = None
    footer: dict[str, Any] = {}
    record: MissionRecord | None = None

    def damaged() -> None:
        out.damaged += 1
        out.first_damaged = out.first_damaged or out.lines

    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            out.lines += 1
            try:
                row = codec.loads_json(line)  # nested too deeply: a ValueError, counted like any damaged line
                kind, value = row["k"], row["v"]
            except (ValueError, KeyError, TypeError):
                damaged()
                continue
            if kind == "header" and isinstance(value, dict) and head is None:
                head = value
                try:
                    record = MissionRecord.model_validate(head)
                except ValueError:
                    head = None
                    damaged()
                    continue
            elif kind == "footer" and isinstance(value, dict):
                footer = value
                out.footer = True
            elif kind in ITEM_MODELS and record is not None:  # the Recorder writes the header first
                try:
                    item = ITEM_MODELS[kind].model_validate(value)
                except ValueError:
                    damaged()
                    continue
                out.items += 1
                keep(record, kind, item, caps)
            else:
                damaged()
    if record is None:
        raise ValueError(f"{path}: not a mission journal (no header line)")
    if footer:
        lists = {k: getattr(record, k) for k in ITEM_MODELS}
        not_kept = dict(record.not_kept)
        try:
            record = MissionRecord.model_validate({**head, **footer, **{k: [] for k in ITEM_MODELS}})
        except ValueError:  # a footer that parses as JSON but not as a record: damaged too
            out.footer = False
            damaged()
        else:
            for k, items in lists.items():
                setattr(record, k, items)
            record.not_kept = not_kept  # what this reading let go, not what the live record did
    record.recording_errors = [*record.recording_errors, *out.notes(path)]
    return record, out


def load_journal(path: str | Path, caps: dict[str, int] | None = None) -> MissionRecord:
    """The record of :func:`read_journal` alone."""
    return read_journal(path, caps)[0]
