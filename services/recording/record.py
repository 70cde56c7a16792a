"""What the ground station records during a mission: the input of the mission report.

Design notes: docs/recording.md (services/recording/record.py).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, model_validator

from protocol.messages import DefectReport, Event, LinkStats, MissionPlan, VehicleState
from protocol.scenario import Scenario

#: A UAV reached its goal when, at the end of its trajectory (progress 1, before landing), it is
#: this close to its last planned waypoint, m. The mission's verdict and the report both use it.
GOAL_RADIUS_M = 2.0


def capture_name(uav: int, capture_id: int) -> str:
    """A capture's name in the verdict, the report and the logged frames' files: ``uav<N>-<capture, 5 digits>``."""
    return f"uav{uav}-{capture_id:05d}"


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
    method: Annotated[str, StringConstraints(pattern=r"^[a-z0-9+-]{1,32}$")] | None = Field(default=None, description="the detection method of the mission's detector, named "
                               "in the inspection findings (None: not known)")
    transport: dict[Literal["reliable", "best-effort"], Annotated[str, StringConstraints(pattern=r"^[a-z0-9]{1,16}$")]] = Field(
        default={}, description="the protocol each link class rode on the ground "
                                      "station's session, 'reliable' / 'best-effort' -> tls, tcp, udp, ... "
                                      "(protocol.links.transports; empty: not known)")
    success: bool = False
    failures: list[str] = []
    phases: dict[str, float] = Field(default={}, description="phase name -> wall time it began")
    recording_errors: list[str] = Field(default=[], description="what went wrong writing the record, and where "
                                        "the data went")
    not_kept: dict[str, int] = Field(default={}, description="items of each kind the in-memory record did not keep "
                                     "(over its cap, LiveRecord); the mission log has them")
    imagery: dict[int, dict[str, int | None]] = Field(default={}, description="per UAV: frames sent, received, "
                                                      "analysed, reported (services.gcs.evidence.ledger)")
    held_captures: list[tuple[int, int]] | None = Field(
        default=None, description="(uav, capture) reported on a frame the ground station received itself, as "
                                  "named (services.recording.witness); None: not checked (no mission log)")
    rejected: dict[str, int] = Field(default={}, description="samples the ground station refused, 'key|kind' -> "
                                     "count: undecodable, or over a source's budget (protocol.budget)")
    report_input: str = Field(default="", description="what the report was computed from: the mission log read "
                              "back, or the in-memory record and why (services.gcs.journal.report_record)")

    @model_validator(mode="after")
    def _no_success_with_failures(self) -> MissionRecord:
        """A record read back with failures is not a success, whatever its ``success`` says."""
        if self.failures:
            self.success = False
        return self


# ============================================================================ streamed, bounded recording
#: free space the output folder must have when a mission starts, bytes (a 1-hour mission's log at
#: the budgets' rates is well under this; protocol.budget)
MIN_FREE_BYTES = 64 * 1024 * 1024
#: items of each kind the in-memory record keeps (the log keeps all). States beyond the cap are
#: decimated (every other one dropped, so the whole flight stays, at half the rate); the others stop.
CAPS: dict[str, int] = {"states": 200_000, "defects": 20_000, "events": 2_000, "gateway_stats": 10_000,
                        "detector_stats": 10_000, "commands": 20_000, "faults": 1_000, "incidents": 10_000}
#: the record's lists of items, and their item models
ITEM_MODELS: dict[str, type[BaseModel]] = {"states": StateRx, "defects": DefectRx, "events": EventRx,
                                           "gateway_stats": StatsRx, "detector_stats": StatsRx,
                                           "commands": CommandRecord, "faults": FaultRecord, "incidents": Incident}


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
    (:class:`LiveRecord`) and of the log read back (:func:`services.recording.load.load_record`)."""
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


class LiveRecord:
    """The ground station's in-memory record (bounded, :data:`CAPS`) and, when a mission log is written, the
    ground station's own entries to it (``sink``: :class:`services.recording.recorder.MissionLogWriter`; the bus's
    samples reach the log by its own subscription). The caller holds its lock around :meth:`add`."""

    #: the lists whose items are the ground station's own (not bus samples)
    OWN = ("commands", "faults", "incidents")

    def __init__(self, record: MissionRecord, sink=None, caps: dict[str, int] | None = None):
        self.record, self.sink = record, sink
        self.caps = {**CAPS, **(caps or {})}
        if sink is not None:
            sink.begin(record)

    def add(self, kind: str, item: BaseModel, own: bool | None = None) -> None:
        """Append ``item`` to the record's list ``kind`` (within its cap); to the log too when it is the ground
        station's own (``own``; default: the kinds of :attr:`OWN`)."""
        keep(self.record, kind, item, self.caps)
        if self.sink is not None and (kind in self.OWN if own is None else own):
            self.sink.add(kind, item, getattr(item, "rx", None) or getattr(item, "at", None))
