"""The launcher's typed configuration (``skynet up`` / ``skynet mission``): each option once, with its default.

Design notes: docs/architecture.md (services/orchestration/config.py).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, Field, model_validator

from edge.config import CAPTURE_LINKS, FRAME_SIZE, EdgeConfig, Flight, FrameSize, Niceness, RateHz, Vehicle
from protocol import keys
from protocol.cliconfig import Cli, CliModel, default_of
from services import attach
from services.detector.config import DetectorConfig, Method
from services.gateway.ingress import STATE_INGRESS_HZ
from services.gcs.config import GcsMissionConfig
from services.video.config import VideoCodec, VideoConfig

from . import trustmode
from .autopilots import autopilot_endpoints
from .fleet_load import EDGE_NICE, GCS_STATE_BUDGET, NICE_ABOVE, PREVIEW_BUDGET

#: the metavar of ``--fault``
FAULT = '"AT ACTION TARGET [for D]"'


def _impair(text: str) -> str:
    """An ``--impair`` value read by the one grammar (its link names are checked against the fleet in the plan)."""
    from services.netem.model import parse_impair_arg

    parse_impair_arg(text)
    return text


#: one ``--impair [LINK[/udp|/tcp]=]SPEC``
ImpairItem = Annotated[str, AfterValidator(_impair)]


class LaunchConfig(CliModel):
    """The options of ``skynet up``: the fleet, its sites, impairments, faults, trust and extra services."""

    uavs: Annotated[int, Cli(metavar="N")] = Field(default=3, ge=1, le=255, description="number of UAVs")
    scenario: str | None = Field(default=None, description="scenario file (default: the paper's monorail bridge)")
    speed: float = Field(default=4.0, description="simulation speed factor (1 = real time)")
    camera: str = Field(default=default_of(EdgeConfig, "camera"), description="synthetic | an image folder | video:<url>")
    frame_size: Annotated[FrameSize | None, Cli(metavar="WxH")] = Field(
        default=None, description=f"capture frame size WxH (default: {FRAME_SIZE[0]}x{FRAME_SIZE[1]}, or the camera's own "
                                  "resolution when the scenario asks for full frames; 4000x3000: the paper's 12 MP)")
    preview_hz: Annotated[RateHz | None, Cli(metavar="HZ")] = Field(default=None, description=(
        f"live preview frames per UAV per second (default: {PREVIEW_BUDGET:g} for the fleet, at most the edge's 2 per "
        "UAV; 0 = off)"))
    gcs_state_hz: Annotated[RateHz | None, Cli(metavar="HZ")] = Field(default=None, description=(
        f"states per UAV per second the gateway forwards to the ground station (0: all, 20 Hz; default: all up to "
        f"{GCS_STATE_BUDGET:g} for the fleet, else {GCS_STATE_BUDGET:g}/N)"))
    netns: bool = Field(default=False, description=(
        "each site in a network namespace of its own, as a stand-in for a host (root; services/orchestration/netns.py):"
        " router links over veth pairs through skynet netem's proxy, site 0 reached from here through a Unix socket "
        "bridge"))
    edge_nice: Annotated[Niceness | None, Cli(metavar="N")] = Field(default=None, description=(
        f"the edges' niceness (default: {EDGE_NICE} above {NICE_ABOVE} UAVs, else 0; "
        "services/orchestration/fleet_load.py)"))
    state_ingress_hz: Annotated[RateHz | None, Cli(metavar="HZ")] = Field(default=None, description=(
        f"states per UAV key the gateway lets in from one session per second (default {STATE_INGRESS_HZ:g}; 0: no "
        "limit; services/gateway/ingress.py)"))
    detect_max_mp: Annotated[float | None, Cli(metavar="MP")] = Field(default=None, description=(
        f"the detector detects frames above MP megapixels on a reduced decode (its default "
        f"{default_of(DetectorConfig, 'detect_max_mp'):g}; 0: never)"))
    capture_link: Literal[CAPTURE_LINKS] = Field(  # type: ignore[valid-type]
        default=default_of(EdgeConfig, "capture_link"),
        description="link of capture frames: best-effort (UDP), reliable (TCP), auto: reliable above 1 MP")
    vehicle: Vehicle = Field(default=default_of(EdgeConfig, "vehicle"), description=(
        "sim: the built-in vehicle; mavlink: each edge flies an autopilot over MAVLink: its --autopilot endpoint, "
        "else a sim autopilot (skynet sim-autopilot) started beside it on loopback"))
    autopilot: Annotated[list[str], Cli(metavar="uavN=ENDPOINT")] = Field(default=[], description=(
        "fly UAV N's own autopilot instead of a sim one (repeatable; implies --vehicle mavlink): ENDPOINT as "
        "pymavlink writes it, udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, /dev/ttyUSB0,57600 or "
        "serial:/dev/ttyACM0:921600; docs/hardware-mavlink.md"))
    home_from_autopilot: bool = Field(default=False, description=(
        "--vehicle mavlink: each edge takes its launch point from its autopilot's HOME_POSITION (about the "
        "scenario's geodetic origin) instead of the scenario's formation slot"))
    sim_boot_scale: Annotated[float, Cli(metavar="F")] = Field(default=1.0, ge=0.0, description=(
        "--vehicle mavlink: the sim autopilots' start-up times as a fraction of ArduCopter's (1: GUIDED/AUTO after 42 "
        "simulated s; 0.1 ten times faster; 0 at once)"))
    sim_firmware_version: Literal["4.6", "4.7"] = Field(default="4.6", description=(
        "--vehicle mavlink: the sim autopilots' parameter names and units: 4.6 (stable 4.5/4.6: WPNAV_SPEED cm/s, "
        "RTL_ALT cm, ...) or 4.7 (4.7+: WP_SPD m/s, RTL_ALT_M m, ...)"))
    sim_legacy_mission_request: bool = Field(default=False, description=(
        "--vehicle mavlink: the sim autopilots ask for uploaded mission items with MISSION_REQUEST (as "
        "ArduCopter's firmware may) instead of MISSION_REQUEST_INT"))
    sim_rc_centred: bool = Field(default=False, description=(
        "--vehicle mavlink: the sim autopilots have a pilot's RC on with centred sticks (LOITER holds; without "
        "RC it descends, as ArduCopter does)"))
    sim_firmware: Literal["arducopter", "px4"] = Field(default="arducopter", description=(
        "--vehicle mavlink: the firmware the sim autopilots present, ArduCopter or PX4 (the edges pick the "
        "dialect from its HEARTBEAT)"))
    ready_timeout: Annotated[float, Cli(flag="--ready-timeout-s", metavar="S")] = Field(
        default=default_of(GcsMissionConfig, "ready_timeout"), gt=0.0,
        description="the ground station waits this long for every UAV's autopilot to be ready, then refuses, s")
    flight: Flight = Field(default=default_of(EdgeConfig, "flight"), description=(
        "--vehicle mavlink: guided (position targets) or auto (a waypoint mission flown in AUTO)"))
    method: Method = Field(default=default_of(DetectorConfig, "method"), description="the detector's method")
    detectors: Annotated[int, Cli(metavar="N")] = Field(default=1, description=(
        "detector instances sharing the cameras (detector-K analyses the UAVs with id %% N == K)"))
    sites: Annotated[int, Cli(metavar="S")] = Field(default=1, description=(
        "gateways: one per site, meshed (each dials the lower-numbered ones); formation g (UAVs 3g+1..3g+3) attaches "
        "to site g %% S, the ground station to site 0 (1 <= S <= formations)"))
    rcu_site: Annotated[list[str], Cli(metavar="NAME=K")] = Field(default=[], description=(
        "attach an RCU to site K's gateway (repeatable; default site 0): planner, detector (every instance) or "
        "detector-K"))
    fleet: str = Field(default=keys.DEFAULT_FLEET, description="fleet name (key space prefix)")
    seed: int = Field(default=0, description="seeds the simulation and every proxy (per link)")
    impair: Annotated[list[ImpairItem], Cli(metavar="[LINK[/udp|/tcp]=]SPEC")] = Field(default=[], description=(
        'netem impairment on a link or group of links (repeatable, later wins), e.g. uav2="delay 50ms loss 2%%"; '
        "no LINK: every link; SPEC as in skynet netem --impair"))
    mesh: Literal["direct", "proxied"] | None = Field(default=None, description=(
        "direct: edges dial each other straight; proxied: through a proxy pair per SkyNet link (default: proxied when "
        "a SkyNet link is impaired or faulted)"))
    no_recovery: bool = Field(default=False, description=(
        "capture frames not recoverable: no imagery cache on the edges, no recovery in the detector"))
    fault: Annotated[list[str], Cli(metavar=FAULT)] = Field(default=[], description=(
        "scripted fault (repeatable): kill gateway|uavN|planner|detector, cut uavN|uplinks|planner|detector, "
        "partition uavI-uavJ|uavN|skynet; AT from the network start (skynet mission: from its mission phase's "
        "start; a fault the mission ends before fails it); AT and D on the wall clock, not the simulation's"))
    keys: Annotated[str | None, Cli(metavar="DIR", exclusive="keys")] = Field(default=None, description=(
        f"fleet key set (skynet keys init); default: a development set in ${trustmode.KEYS_ENV} or "
        f"{trustmode.DEFAULT_KEYS}"))
    no_accept_guard: bool = Field(default=False, description=(
        "the gateways accept TLS connections without the guard that drops those not starting a TLS handshake "
        "(connect-and-close or silent floods; services/gateway/guard.py, bench/accept.py)"))
    insecure: Annotated[bool, Cli(exclusive="keys")] = Field(
        default=False, description="no TLS, no access control, unsigned commands: development only")
    video: VideoCodec | None = Field(default=None, description=(
        "also run skynet video: each UAV's preview as RTP/UDP to 127.0.0.1:PORT+2(n-1) (--preview-port)"))
    video_sdp: Annotated[str, Cli(flag="--sdp-dir", metavar="DIR")] = Field(default=default_of(VideoConfig, "sdp_dir"),
                           description="folder of the video streams' SDP files (with --video)")
    video_port: Annotated[int, Cli(flag="--preview-port", metavar="PORT")] = Field(default=default_of(VideoConfig, "port"), description=(
        "UAV 1's preview port (with --video); UAV n's is PORT + 2(n-1)"))
    web: Annotated[str | None, Cli(metavar="[HOST]:PORT")] = Field(default=None, description=(
        "serve the live web page of the fleet there, e.g. :8080 (loopback unless a host is given)"))
    network: Annotated[str | None, Cli(metavar="FILE")] = Field(default=None, description=(
        f"where to describe the running network for skynet web/video/replay (default: ${attach.NETWORK_ENV} or "
        f"{attach.NETWORK_FILE}; removed at the end)"))
    dry_run: bool = Field(default=False, description=(
        "print the network this command would start (every process, its endpoints, identity and command line) and "
        "exit: nothing is started, no key set made"))
    as_json: Annotated[bool, Cli(flag="--json")] = Field(default=False, description="with --dry-run: the plan as JSON")
    #: the detector's frame folder (set by ``skynet mission``: the report's ``frames/``)
    save_frames: Annotated[str | None, Cli(hidden=True)] = None

    @model_validator(mode="after")
    def _json_with_dry_run(self) -> LaunchConfig:
        if self.as_json and not self.dry_run:
            raise ValueError("--json: only with --dry-run")
        return self

    @model_validator(mode="after")
    def _autopilots(self) -> LaunchConfig:
        """``--autopilot`` checked (:func:`.autopilots.autopilot_endpoints`) and implying ``--vehicle mavlink``."""
        if self.autopilot:
            autopilot_endpoints(self.autopilot, self.uavs)
            if self.netns:
                raise ValueError("--autopilot with --netns: the edges' namespaces do not reach this machine's "
                                 "network; run the edges in the machine's own")
            self.vehicle = "mavlink"
        if self.home_from_autopilot and self.vehicle != "mavlink":
            raise ValueError("--home-from-autopilot: only with --vehicle mavlink or --autopilot")
        return self

    def autopilots(self) -> dict[int, str]:
        """UAV -> the endpoint of its own autopilot (``--autopilot``); the others fly a sim autopilot."""
        return autopilot_endpoints(self.autopilot, self.uavs)


class MissionLaunchConfig(LaunchConfig):
    """The options of ``skynet mission``: those of ``skynet up``, the ground station's mission and its report."""

    fault: Annotated[list[str], Cli(metavar=FAULT)] = Field(default=[], description=(
        "scripted fault (repeatable): kill gateway|uavN|planner|detector, cut uavN|uplinks|planner|detector|gcs, "
        "partition uavI-uavJ|uavN|skynet; AT (from the mission phase) and D on the wall clock, the links' time, "
        "not the simulation's: at --speed 8 the mission phase lasts an eighth of its simulated time"))
    out: str | None = Field(default=None, description="report folder (default reports/mission-<time>)")
    quiet: bool = Field(default=False, description="no live progress display")
    algorithm: str = Field(default=default_of(GcsMissionConfig, "algorithm"), description="the planner's algorithm")
    no_record: bool = Field(default=False, description="do not log the mission to OUT/mission.mcap")


#: the options of ``skynet up`` and of ``skynet mission``
MODELS: dict[str, type[LaunchConfig]] = {"up": LaunchConfig, "mission": MissionLaunchConfig}
