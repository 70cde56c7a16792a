"""What the ground station records during a mission: the input of the mission report.

Plain pydantic data (no bus code), serialisable to JSON with ``record.model_dump_json()`` and
back with ``MissionRecord.model_validate_json``, so a report can be re-made from a saved run.
Every ``rx`` field is the wall-clock UNIX time the ground station received the item.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from protocol.messages import DefectReport, Event, LinkStats, MissionPlan, VehicleState

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

    ``action`` is one of kill, restart, cut, restore, partition, heal (services.faults); ``at`` is the
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
    """Something the ground station noticed about a fault, or did about one (issue 7)."""

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
    scenario: dict[str, Any]
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
    faults: list[FaultRecord] = Field(default=[], description="faults injected during the run (services.faults)")
    incidents: list[Incident] = Field(default=[], description="what the ground station saw of faults and did")
    heartbeats_sent: int = 0
    ground_truth: list[GroundTruthDefect] = []
    surface_corners: list[tuple[float, float, float]] = []
    success: bool = False
    failures: list[str] = []
    phases: dict[str, float] = Field(default={}, description="phase name -> wall time it began")
    rejected: dict[str, int] = Field(default={}, description="samples the ground station refused, 'key|kind' -> "
                                     "count: undecodable, or over a source's budget (protocol.budget)")
