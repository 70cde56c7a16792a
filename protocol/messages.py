"""Message schemas: pydantic v2 models for everything that crosses the bus.

Design notes: docs/bus.md (protocol/messages.py).
"""

from __future__ import annotations

import math
from enum import Enum, StrEnum
from typing import Annotated, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from .scenario import Scenario

# Bounds that no sane message exceeds: the fleet operates in boxes of a few km.
MAX_COORD_M = 1.0e5
MAX_SPEED_MS = 100.0

Finite = Annotated[float, Field(allow_inf_nan=False)]
Coord = Annotated[float, Field(ge=-MAX_COORD_M, le=MAX_COORD_M, allow_inf_nan=False)]
Angle = Annotated[float, Field(ge=-4 * math.pi, le=4 * math.pi, allow_inf_nan=False)]
Rate = Annotated[float, Field(ge=-100.0, le=100.0, allow_inf_nan=False)]
Speed = Annotated[float, Field(ge=-MAX_SPEED_MS, le=MAX_SPEED_MS, allow_inf_nan=False)]
Vec3 = tuple[Coord, Coord, Coord]
Vel3 = tuple[Speed, Speed, Speed]
Att3 = tuple[Angle, Angle, Angle]
Rate3 = tuple[Rate, Rate, Rate]
UavId = Annotated[int, Field(ge=1, le=255)]
Seconds = Annotated[float, Field(ge=0.0, le=1.0e10, allow_inf_nan=False)]
Seq = Annotated[int, Field(ge=0, le=2**63 - 1)]
Short = Annotated[str, Field(max_length=256)]
Text = Annotated[str, Field(max_length=4096)]


class Message(BaseModel):
    """Base of every wire message: strict about unknown fields and non-finite numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    #: the type tag written on the wire (see protocol.codec)
    TYPE: ClassVar[str] = ""


# ----------------------------------------------------------------------------- vehicle state
class Mode(str, Enum):
    """Flight modes of the board's state machine."""

    IDLE = "idle"  # on the ground, disarmed
    TAKEOFF = "takeoff"
    HOLD = "hold"  # position hold (also the failsafe action)
    MISSION = "mission"  # following the uploaded trajectory
    LAND = "land"
    RTL = "rtl"  # return to launch
    LANDED = "landed"
    FAILSAFE = "failsafe"
    PILOT = "pilot"  # the autopilot flies a mode the edge did not command (a pilot's); autopilot.mode names it


class AutopilotReadiness(Message):
    """An autopilot's readiness to fly, as its edge sees it (MAVLink vehicles; absent for the built-in sim)."""

    TYPE: ClassVar[str] = "autopilot"
    ready: bool = Field(description="every check below passes: the ground station may command a takeoff")
    heartbeat: bool = Field(description="the autopilot's HEARTBEAT heard within the link timeout")
    status: Annotated[str, Field(max_length=32)] = Field(
        default="", description="its HEARTBEAT system_status (MAV_STATE without the prefix, lower case: boot, standby...)")
    home: bool = Field(default=False, description="its home position is known (HOME_POSITION)")
    position: bool = Field(default=False, description="its position estimate is absolute (EKF_STATUS_REPORT)")
    armable: bool = Field(default=False, description="its pre-arm checks pass (SYS_STATUS pre-arm bit healthy)")
    reason: Short = Field(default="", description="why it is not ready: its own latest pre-arm or refusal text")
    mode: Annotated[str, Field(max_length=32)] = Field(
        default="", description="the autopilot's own flight mode (its dialect's name, e.g. GUIDED, AUTO, LOITER)")
    external: bool = Field(
        default=False, description="that mode is not one the edge commanded (a pilot or the autopilot's failsafe)")


class VehicleState(Message):
    TYPE: ClassVar[str] = "state"
    uav: UavId
    seq: Seq = Field(description="per-UAV telemetry sequence number")
    t: Seconds = Field(description="simulation/mission time, s")
    stamp: Seconds = Field(description="wall-clock UNIX time of publication, s")
    pos: Vec3 = Field(description="ENU position, m")
    vel: Vel3 = Field(description="ENU velocity, m/s")
    att: Att3 = Field(description="roll, pitch, yaw, rad (ZYX Euler)")
    rates: Rate3 = Field(description="body rates p, q, r, rad/s (P10)")
    mode: Mode
    armed: bool = False
    battery: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 1.0
    wp_index: Annotated[int, Field(ge=-1)] = -1
    progress: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0
    captures: Annotated[int, Field(ge=0)] = 0
    neighbours: Annotated[int, Field(ge=0, le=255)] = Field(
        default=0, description="other UAVs whose state was heard over SkyNet within the stale limit")
    ref: Vec3 | None = Field(default=None, description="planned position (own slot, P9) now, ENU m; in MISSION")
    tau: Seconds | None = Field(default=None, description="trajectory time now, s; in MISSION")
    autopilot: AutopilotReadiness | None = Field(
        default=None, description="the autopilot's readiness (MAVLink vehicles); None: the built-in vehicle, always ready")


# ----------------------------------------------------------------------------- trajectories
class Waypoint(Message):
    TYPE: ClassVar[str] = "waypoint"
    t: Seconds = Field(description="time from trajectory start, s")
    pos: Vec3 = Field(description="ENU position, m")
    yaw: Angle = 0.0
    speed: Annotated[float, Field(ge=0.0, le=MAX_SPEED_MS, allow_inf_nan=False)] = 0.0
    capture_id: Annotated[int, Field(ge=0)] | None = Field(
        default=None, description="fire the camera here, with this capture id")


class Trajectory(Message):
    """A time-parametrised path for one UAV (P9)."""

    TYPE: ClassVar[str] = "trajectory"
    uav: UavId
    waypoints: list[Waypoint] = Field(min_length=1, max_length=20000)

    @field_validator("waypoints")
    @classmethod
    def _increasing_time(cls, wps: list[Waypoint]) -> list[Waypoint]:
        for a, b in zip(wps, wps[1:]):
            if not b.t > a.t:
                raise ValueError("waypoint times must be strictly increasing")
        return wps


class Box(Message):
    """The operation box (geofence), ENU metres."""

    TYPE: ClassVar[str] = "box"
    lo: Vec3
    hi: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> Box:
        if any(h <= l for l, h in zip(self.lo, self.hi)):
            raise ValueError("box hi must exceed lo on every axis")
        return self

    def contains(self, p: tuple[float, float, float], margin: float = 0.0) -> bool:
        return all(l - margin <= v <= h + margin for l, v, h in zip(self.lo, p, self.hi))


# ----------------------------------------------------------------------------- commands
class _Cmd(Message):
    uav: UavId
    cmd_id: Annotated[int, Field(ge=0)]


class UploadTrajectory(_Cmd):
    TYPE: ClassVar[str] = "cmd.upload"
    kind: Literal["upload"] = "upload"
    trajectory: Trajectory
    geofence: Box | None = None


class Takeoff(_Cmd):
    TYPE: ClassVar[str] = "cmd.takeoff"
    kind: Literal["takeoff"] = "takeoff"
    altitude: Annotated[float, Field(gt=0.0, le=500.0, allow_inf_nan=False)] = 5.0


class Start(_Cmd):
    """Start following the uploaded trajectory (first flying to its first waypoint)."""

    TYPE: ClassVar[str] = "cmd.start"
    kind: Literal["start"] = "start"
    t0_stamp: Seconds | None = Field(default=None, description="common wall-clock start, UNIX s")


class Land(_Cmd):
    TYPE: ClassVar[str] = "cmd.land"
    kind: Literal["land"] = "land"


class Hold(_Cmd):
    TYPE: ClassVar[str] = "cmd.hold"
    kind: Literal["hold"] = "hold"


class Resume(_Cmd):
    TYPE: ClassVar[str] = "cmd.resume"
    kind: Literal["resume"] = "resume"


class ReturnToLaunch(_Cmd):
    TYPE: ClassVar[str] = "cmd.rtl"
    kind: Literal["rtl"] = "rtl"


class SetFormation(_Cmd):
    """Desired formation offsets ΔT_n of every UAV (P9), ENU-like formation frame, m."""

    TYPE: ClassVar[str] = "cmd.formation"
    kind: Literal["formation"] = "formation"
    offsets: dict[Annotated[int, Field(ge=1, le=255)], Vec3] = Field(min_length=1, max_length=255)


Command = Annotated[
    UploadTrajectory | Takeoff | Start | Land | Hold | Resume | ReturnToLaunch | SetFormation,
    Field(discriminator="kind"),
]
COMMAND_TYPES = (UploadTrajectory, Takeoff, Start, Land, Hold, Resume, ReturnToLaunch, SetFormation)


class CommandAck(Message):
    TYPE: ClassVar[str] = "cmd.ack"
    uav: UavId
    cmd_id: Annotated[int, Field(ge=0)]
    accepted: bool
    reason: Text = ""


class Heartbeat(Message):
    """The ground station's command-link heartbeat that the edges' failsafe watches."""

    TYPE: ClassVar[str] = "heartbeat"
    source: Short = "gcs"
    seq: Seq
    stamp: Seconds


class Signed(Message):
    """An end-to-end signed envelope around a command or heartbeat (see :mod:`protocol.signing`)."""

    TYPE: ClassVar[str] = "signed"
    signer: Annotated[str, Field(min_length=1, max_length=64)]
    kid: Annotated[str, Field(pattern=r"^[0-9a-f]{16}$")] = Field(description="signer key id")
    seq: Seq = Field(description="strictly increasing per signer and addressee")
    stamp: Seconds = Field(description="wall-clock UNIX time of signing, s")
    to: Short = Field(description="the addressee: the key expression it is sent on")
    type: Short = Field(description="wire tag of the inner message")
    body: Annotated[str, Field(max_length=12 * 1024 * 1024)] = Field(description="the inner message's codec bytes, base64")
    sig: Annotated[str, Field(max_length=128)] = Field(description="Ed25519 signature, base64")


# ----------------------------------------------------------------------------- planning
#: a request's nonce: 16 to 64 lower-case hex digits (``""``: an unbound request)
Nonce = Annotated[str, Field(max_length=64, pattern=r"^([0-9a-f]{16,64})?$")]
#: a SHA-256 digest in hex (``""``: none)
Digest = Annotated[str, Field(max_length=64, pattern=r"^([0-9a-f]{64})?$")]


class PlanRequest(Message):
    TYPE: ClassVar[str] = "plan.request"
    request_id: Annotated[int, Field(ge=0)] = 0
    nonce: Nonce = Field("", description="fresh random hex per request; the plan must echo it (protocol.planauth)")
    scenario: Scenario = Field(description="the whole planning problem (protocol.scenario)")
    algorithm: Short = "theta-pso"
    seed: Annotated[int, Field(ge=0)] = 0
    particles: Annotated[int, Field(ge=2, le=10000)] | None = None
    iterations: Annotated[int, Field(ge=1, le=100000)] | None = None
    waypoints: Annotated[int, Field(ge=1, le=200)] | None = None


class CapturePoint(Message):
    TYPE: ClassVar[str] = "capture"
    capture_id: Annotated[int, Field(ge=0)]
    uav: UavId
    pos: Vec3 = Field(description="camera position, ENU m")
    look: Vec3 = Field(description="unit optical axis (towards the surface), ENU")
    t: Seconds = Field(description="time on the UAV's trajectory, s")


class MissionPlan(Message):
    TYPE: ClassVar[str] = "plan"
    request_id: Annotated[int, Field(ge=0)] = 0
    algorithm: Short
    seed: Annotated[int, Field(ge=0)]
    cost: Finite
    collision_free: bool
    centroid_path: list[Vec3] = Field(min_length=2)
    trajectories: list[Trajectory] = Field(min_length=1)
    captures: list[CapturePoint] = []
    convergence: list[Finite] = []
    planning_time_s: Seconds = 0.0
    geofence: Box
    origin: tuple[Finite, Finite, Finite] = Field(description="geodetic origin lat, lon (deg), alt (m)")
    standoff_m: Finite = 0.0
    nonce: Nonce = Field("", description="the request's nonce (protocol.planauth)")
    scenario_digest: Digest = Field("", description="SHA-256 of the request's scenario (protocol.planauth)")


class ErrorReply(Message):
    """The body of a ``reply_err``: why a request was refused."""

    TYPE: ClassVar[str] = "error"
    code: Short
    reason: Text


# ----------------------------------------------------------------------------- imagery
class Intrinsics(Message):
    TYPE: ClassVar[str] = "intrinsics"
    width: Annotated[int, Field(ge=1, le=20000)]
    height: Annotated[int, Field(ge=1, le=20000)]
    fx: Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
    fy: Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
    cx: Finite
    cy: Finite


class ImageMeta(Message):
    """Metadata of one camera frame, sent with the encoded image on the imagery link."""

    TYPE: ClassVar[str] = "image.meta"
    uav: UavId
    capture_id: Annotated[int, Field(ge=0)]
    t: Seconds
    stamp: Seconds = Field(description="wall-clock capture time, UNIX s")
    cam_pos: Vec3 = Field(description="camera position, ENU m")
    cam_rot: tuple[Finite, Finite, Finite, Finite, Finite, Finite, Finite, Finite, Finite] = Field(
        description="world-from-camera rotation, row-major 3x3 (OpenCV camera axes: x right, y down, z forward)")
    intrinsics: Intrinsics
    encoding: Literal["jpeg", "png"] = "jpeg"
    range_m: Annotated[float, Field(gt=0.0, le=1000.0, allow_inf_nan=False)] | None = Field(
        default=None, description="distance to the surface along the optical axis, m (rangefinder or plan)")


class Defect(Message):
    TYPE: ClassVar[str] = "defect"
    area_px: Annotated[int, Field(ge=0)]
    bbox: tuple[int, int, int, int] = Field(description="x, y, w, h in pixels")
    centroid_px: tuple[Finite, Finite]
    contrast: Finite
    pos: Vec3 | None = Field(default=None, description="ENU position on the surface, m")
    length_m: Finite | None = None


class FrameEvidence(Message):
    """The frame a defect report was computed from: its RTP source and sequence number (RFC 3550 §5.1) and
    the SHA-256 of the image bytes the detector analysed (a capture counts only with it)."""

    TYPE: ClassVar[str] = "frame.evidence"
    ssrc: Annotated[int, Field(ge=0, le=2**32 - 1)]
    seq: Annotated[int, Field(ge=0, le=65535)]
    digest: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]


class DefectReport(Message):
    TYPE: ClassVar[str] = "defects"
    uav: UavId
    capture_id: Annotated[int, Field(ge=0)]
    stamp_capture: Seconds
    stamp_report: Seconds
    method: Short
    threshold: Finite = 0.0
    ok: bool = True
    error: Text = ""
    defects: list[Defect] = Field(default=[], max_length=10000)
    defect_fraction: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0
    frame: FrameEvidence | None = Field(default=None, description="the frame analysed (None: no evidence)")


# ----------------------------------------------------------------------------- stats and events
class ClassCounters(Message):
    TYPE: ClassVar[str] = "class.counters"
    samples: Annotated[int, Field(ge=0)] = 0
    bytes: Annotated[int, Field(ge=0)] = 0


class LinkStats(Message):
    TYPE: ClassVar[str] = "link.stats"
    source: Short
    stamp: Seconds
    uptime_s: Seconds = 0.0
    sessions: dict[Short, Annotated[int, Field(ge=0)]] = {}
    classes: dict[Short, ClassCounters] = {}
    rejected: dict[Short, Annotated[int, Field(ge=0)]] = {}
    metrics: dict[Short, Finite] = Field(default={}, description="named figures, e.g. uav1.jitter_ms")


class Level(str, Enum):
    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


class EventKind(StrEnum):
    """What an :class:`Event` reports; every kind a node publishes, and no other (an unknown kind is a schema
    failure, rejected and counted as an unknown field is: every publisher is part of this system).

    A UAV's board (edge.board, edge.failsafe) and the ground station (services.gcs.mission) publish them."""

    NEIGHBOUR_UP = "neighbour-up"  # a formation member's liveliness token appeared
    NEIGHBOUR_LOST = "neighbour-lost"  # ... and left (the member left SkyNet)
    NEIGHBOUR_STALE = "neighbour-stale"  # a formation member's state is older than the stale limit
    NEIGHBOUR_FRESH = "neighbour-fresh"  # ... and heard again
    TRUST_REFUSED = "trust-refused"  # a command, heartbeat or state refused by the trust gate (rate-limited)
    COMMAND_REJECTED = "command-rejected"  # a command refused by validation or the vehicle
    GEOFENCE_NARROWED = "geofence-narrowed"  # a signed upload narrowed the board's geofence
    PILOT_MODE = "pilot-mode"  # the autopilot entered a mode the edge did not command
    FAILSAFE = "failsafe"  # the ground station's heartbeat lost: the failsafe action (data: action, ok)
    FAILSAFE_ESCALATED = "failsafe-escalated"  # a failsafe hold escalated (rtl or land)
    FAILSAFE_RETRY = "failsafe-retry"  # a failsafe action the vehicle did not take, tried again or replaced
    FAILSAFE_CLEARED = "failsafe-cleared"  # a Resume ended the failsafe (data: since, held_s)
    BATTERY_FAILSAFE = "battery-failsafe"  # a low (rtl) or critical (land) battery
    PLAN_CONFLICT = "plan-conflict"  # the ground station got differing plans for one request
    PLAN_REFUSED = "plan-refused"  # the ground station refused a plan answer


class Event(Message):
    TYPE: ClassVar[str] = "event"
    source: Short
    stamp: Seconds
    kind: EventKind
    level: Level = Level.INFO
    text: Text = ""
    data: dict[Short, bool | int | Finite | Short] = {}


#: every message type, by wire tag
MESSAGE_TYPES: dict[str, type[Message]] = {
    m.TYPE: m
    for m in (VehicleState, Waypoint, Trajectory, Box, *COMMAND_TYPES, CommandAck, Heartbeat, Signed, PlanRequest,
              CapturePoint, MissionPlan, ErrorReply, Intrinsics, ImageMeta, Defect, FrameEvidence, DefectReport,
              ClassCounters, LinkStats, Event)
}
