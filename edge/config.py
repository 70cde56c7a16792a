"""The edge's typed configuration (``skynet edge``): every option of the board, its one default, its checks.

Design notes: docs/edge.md (edge/config.py).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, PlainSerializer, model_validator

from protocol.bus import BusMode, BusOptions, LeaseS
from protocol.cliconfig import Cli, arg_type
from protocol.links import LINK_LEASE_S
from protocol.messages import Box

from .board import BoardOptions
from .failsafe import ACTIONS, ESCALATIONS, FailsafeOptions

#: capture frames each camera keeps for retransmission of frames lost on the way
IMAGERY_CACHE_FRAMES = 32
#: live preview rate (wall clock, Hz) and frame size
PREVIEW_HZ = 2.0
PREVIEW_SIZE = (320, 240)
#: ``--capture-link``: auto is reliable above a size (edge.camera_service.capture_link)
CAPTURE_LINKS = ("auto", "best-effort", "reliable")
#: the delivered capture frame size, (width, height) pixels
FRAME_SIZE = (640, 480)

#: the board's and the failsafe's own defaults, which the command line's are (one place for each value)
_BOARD = BoardOptions(uav=1)
_FAILSAFE = _BOARD.failsafe


def parse_size(text: Any) -> Any:
    """``WxH`` (e.g. ``640x480``) as (W, H); a pair is passed on for the type's checks."""
    if isinstance(text, str):
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError:
            raise ValueError(f"expected WxH (e.g. 640x480), got {text!r}") from None
        return w, h
    return text


def _floats(n: int, what: str):
    def parse(text: Any) -> Any:
        if isinstance(text, str):
            try:
                v = tuple(float(x) for x in text.split(","))
            except ValueError:
                raise ValueError(f"expected {what}, got {text!r}") from None
            if len(v) != n or not all(map(math.isfinite, v)):
                raise ValueError(f"expected {what}, got {text!r}")
            return v
        return text
    return parse


def _box(text: Any) -> Any:
    if isinstance(text, str):
        v = _floats(6, "x0,y0,z0,x1,y1,z1")(text)
        return Box(lo=v[:3], hi=v[3:])
    return text


def _join(values) -> str:
    """Comma-separated, short and exact (``0`` not ``0.0``; never rounded: the value parses back the same)."""
    return ",".join(f"{float(v):g}" if float(f"{float(v):g}") == float(v) else repr(float(v)) for v in values)


Side = Annotated[int, Field(ge=16, le=20000)]
#: a frame size, (W, H) pixels with each side 16..20000, written ``WxH``
FrameSize = Annotated[tuple[Side, Side], BeforeValidator(parse_size), PlainSerializer(lambda s: f"{s[0]}x{s[1]}")]
#: a point x,y,z (ENU m), written ``x,y,z``
Vec3 = Annotated[tuple[float, float, float], BeforeValidator(_floats(3, "x,y,z")), PlainSerializer(_join)]
#: a box x0,y0,z0,x1,y1,z1
BoxArg = Annotated[Box, BeforeValidator(_box), PlainSerializer(lambda b: _join((*b.lo, *b.hi)))]
#: a ``nice(2)`` increment: 0..19 (19 is the lowest priority)
Niceness = Annotated[int, Field(ge=0, le=19)]
#: a rate in Hz, 0 meaning off
RateHz = Annotated[float, Field(ge=0.0)]

#: the vehicle driver and, with MAVLink, its flight strategy
Vehicle = Literal["sim", "mavlink"]
Flight = Literal["guided", "auto"]

#: the argparse type of a niceness given as text
niceness = arg_type(Niceness, "niceness")


class EdgeConfig(BusOptions):
    """The options of one UAV's board (``skynet edge``)."""

    mode: BusMode = "peer"
    lease: LeaseS = LINK_LEASE_S
    uav: int = Field(ge=1, le=255, description="this UAV's id")
    vehicle: Vehicle = Field(default="sim", description="vehicle driver")
    mavlink: str = Field(default="udpin:0.0.0.0:14550", description="MAVLink connection (--vehicle mavlink)")
    mavlink_key: str | None = Field(
        default=None, description="MAVLink 2 signing key for the autopilot link: 64 hex digits or a passphrase")
    mavlink_gcs: Annotated[str | None, Cli(metavar="ENDPOINT")] = Field(
        default=None, description="MAVLink endpoint for the operator's ground station (autopilot traffic forwarded), "
                                  "e.g. udpout:127.0.0.1:14560")
    flight: Flight = Field(
        default="guided", description="--vehicle mavlink: guided streams position targets; auto uploads the "
                                      "trajectory as a waypoint mission and flies it in AUTO, kept in formation by "
                                      "speed corrections")
    mavlink_video: Annotated[int | None, Cli(metavar="BASE_PORT")] = Field(
        default=None, ge=1, le=65535,
        description="with --mavlink-gcs: announce the preview stream of skynet video --preview-port BASE_PORT "
                    "(this UAV's port BASE_PORT+2(uav-1)) as MAVLink VIDEO_STREAM_INFORMATION")
    home: Vec3 = Field(default=(0.0, 0.0, 0.0), description="launch point x,y,z (ENU m)")
    home_from_autopilot: bool = Field(default=False, description=(
        "--vehicle mavlink: the launch point is the autopilot's HOME_POSITION in the scenario's ENU frame (about "
        "its geodetic origin), not --home"))
    rate: Annotated[float, Cli(flag="--rate-hz", metavar="HZ")] = Field(
        default=_BOARD.rate_hz, gt=0.0, le=1000.0, description="state publication rate, Hz")
    stale: Annotated[float, Cli(flag="--stale-s", metavar="S")] = Field(
        default=_BOARD.stale_s, gt=0.0, description="neighbour state considered stale after, s")
    formation_gain: float = Field(default=_BOARD.formation_gain, ge=0.0, le=1.0,
                                  description="share of the neighbours' mean position error corrected on board, 0..1")
    formation_size: int = Field(default=_BOARD.formation_size, ge=1,
                                description="UAVs per formation: the board shares state with its formation only "
                                            "(SkyNet)")
    failsafe_timeout: Annotated[float, Cli(flag="--failsafe-timeout-s", metavar="S")] = Field(default=_FAILSAFE.timeout_s, gt=0.0,
                                    description="no ground-station heartbeat for this long while flying: failsafe, s")
    failsafe_action: Literal[ACTIONS] = Field(default=_FAILSAFE.action,  # type: ignore[valid-type]
                                              description="the link failsafe's action")
    failsafe_escalate: Literal[ESCALATIONS] = Field(  # type: ignore[valid-type]
        default=_FAILSAFE.escalate_action, description="after a failsafe hold of --failsafe-escalate-after-s: rtl, "
                                                       "land or none")
    failsafe_escalate_after: Annotated[float, Cli(flag="--failsafe-escalate-after-s", metavar="S")] = Field(
        default=_FAILSAFE.escalate_after_s, ge=0.0, description="a failsafe hold lasting this long escalates, s")
    battery_low: float = Field(default=_FAILSAFE.battery_low, ge=0.0, le=1.0, description=(
        "battery failsafe: return to launch below this charge (fraction of full, 0..1)"))
    battery_critical: float = Field(default=_FAILSAFE.battery_critical, ge=0.0, le=1.0, description=(
        "battery failsafe: land below this charge (fraction of full, 0..1)"))
    endurance: Annotated[float | None, Cli(flag="--endurance-s", metavar="S")] = Field(
        default=None, gt=0.0, description="simulated vehicle: hover time on a full battery, s (default 1200)")
    geofence: BoxArg | None = Field(default=None, description="x0,y0,z0,x1,y1,z1 (else from upload)")
    speed: float = Field(default=1.0, gt=0.0, description="simulation speed factor")
    epoch: float | None = Field(default=None, description="shared wall-clock epoch of the sim clock")
    seed: int | None = Field(default=None, description="simulated vehicle's random seed (default: the UAV id)")
    wind: Literal["calm", "moderate"] = Field(
        default="moderate", description="disturbance model of the simulated vehicle (seeded gusts and torques)")
    camera: str = Field(default="synthetic", description="synthetic | image folder | video:<url or index> | none")
    scenario: str | None = Field(default=None, description="scenario file (surface and camera of the synthetic source)")
    frame_size: FrameSize = Field(default=FRAME_SIZE, description="delivered frame size WxH")
    capture_link: Literal[CAPTURE_LINKS] = Field(  # type: ignore[valid-type]
        default="auto", description="link of capture frames: best-effort (UDP), reliable (TCP), or auto: reliable "
                                    "above 1 MP")
    preview_hz: Annotated[RateHz, Cli(metavar="HZ")] = Field(
        default=PREVIEW_HZ, description="live preview frames per second (320x240, best-effort, never recovered; "
                                        "0 = off)")
    nice: Annotated[Niceness, Cli(metavar="N")] = Field(
        default=0, description="lower this board's CPU priority by N (0..19): a simulated fleet sharing one machine "
                               "with the services (services.orchestration.fleet_load)")
    imagery_cache: Annotated[int, Cli(metavar="N")] = Field(
        default=IMAGERY_CACHE_FRAMES, ge=0, description="capture frames kept for retransmission to a detector that "
                                                        "lost them (0: no recovery, capture frames are best-effort "
                                                        "like previews)")
    trust_window: Annotated[float, Cli(flag="--trust-window-s", metavar="S", group="trust (see edge.trust)")] = Field(
        default=10.0, gt=0.0, description="signed commands and heartbeats stamped further than this from now are "
                                          "stale, s")
    mesh_uavs: Annotated[int | None, Cli(flag="--uavs", metavar="N", group="trust (see edge.trust)")] = Field(
        default=None, ge=1, le=255, description="UAVs 1..N may link to this edge (ACL by certificate; default: those "
                                                "of --keys)")
    replay_state: Annotated[str | None, Cli(metavar="FILE", group="trust (see edge.trust)")] = Field(
        default=None, description="where the replay window is kept (default: <keys>/uavN/replay.json; a read-only "
                                  "key set needs one)")
    insecure: Annotated[bool, Cli(group="trust (see edge.trust)", exclusive="keys")] = Field(
        default=False, description="accept unsigned commands and heartbeats, no TLS, no ACL (development only)")

    @model_validator(mode="after")
    def _consistent(self) -> EdgeConfig:
        if self.battery_critical > self.battery_low:
            raise ValueError(f"--battery-critical {self.battery_critical} is above --battery-low {self.battery_low}")
        return self

    def failsafe(self) -> FailsafeOptions:
        """The link and battery failsafes' options (edge.failsafe)."""
        return FailsafeOptions(timeout_s=self.failsafe_timeout, action=self.failsafe_action,
                               escalate_after_s=self.failsafe_escalate_after, escalate_action=self.failsafe_escalate,
                               battery_low=self.battery_low, battery_critical=self.battery_critical)
