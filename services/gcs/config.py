"""The ground control station's typed configuration (``skynet gcs``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, field_validator

from protocol.bus import BusMode, BusOptions
from protocol.cliconfig import Cli, default_of
from services.detector.config import DetectorConfig, Method

from .mission import MissionOptions

#: the mission's own defaults, which the command line's are (one place for each value)
_MISSION = MissionOptions()


class GcsMissionConfig(BusOptions):
    """The options of ``skynet gcs``: a mission run over the bus, and its report."""

    mode: BusMode = "client"
    scenario: str | None = Field(default=None, description="scenario file (default: the paper's monorail bridge)")
    uavs: Annotated[int, Cli(metavar="N")] = Field(default=len(_MISSION.uavs), ge=1, le=255, description="number of UAVs (ids 1..N)")
    algorithm: str = Field(default=_MISSION.algorithm, pattern=r"^[a-z0-9+-]{1,32}$",
                           description="the planner's algorithm")
    seed: int = Field(default=_MISSION.seed, ge=0, description="the planner's seed")
    speed: float = Field(default=_MISSION.speed, gt=0.0, le=1000.0, description="the edges' simulation speed factor")
    out: str | None = Field(default=None, description="report folder")
    quiet: bool = Field(default=False, description="no live progress display")
    appear_timeout: Annotated[float, Cli(flag="--appear-timeout-s", metavar="S")] = Field(
        default=_MISSION.appear_timeout_s, gt=0.0, description="wait this long for every UAV to appear, s")
    ready_timeout: Annotated[float, Cli(flag="--ready-timeout-s", metavar="S")] = Field(
        default=_MISSION.ready_timeout_s, gt=0.0,
        description="wait this long for every UAV's autopilot to be ready before takeoff, then refuse, s")
    no_record: bool = Field(default=False, description="do not log the mission to OUT/mission.mcap")
    method: Method = Field(default=default_of(DetectorConfig, "method"),
                           description="the detection method of the mission's detector (skynet detector --method): "
                                       "kept in the mission log and named in the findings")
    web: Annotated[str | None, Cli(metavar="[HOST]:PORT")] = Field(
        default=None, description="serve the live web page of the fleet there (e.g. :8080; loopback unless a host "
                                  "is given)")
    no_ground_truth: bool = Field(
        default=False, description="the edges do not image the synthetic wall (real cameras, image folders): no "
                                   "defect scoring")

    @field_validator("web")
    @classmethod
    def _web(cls, v: str | None) -> str | None:
        if v is not None:
            from services.web.server import parse_listen

            parse_listen(v)
        return v
