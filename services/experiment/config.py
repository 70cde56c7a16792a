"""``skynet experiment``'s typed configuration: the grid of link conditions and how each run is flown."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BeforeValidator, Field, PlainSerializer, model_validator

from edge.config import EdgeConfig, Flight, Vehicle
from protocol.cliconfig import Cli, CliModel, default_of
from services.detector.config import DetectorConfig, Method

from .grid import check_links, parse_list, parse_recovery


def _values(name: str, hi: float):
    def parse(text: Any) -> Any:
        return parse_list(text, name, hi=hi) if isinstance(text, str) else text
    return parse


def _recovery(text: Any) -> Any:
    return parse_recovery(text) if isinstance(text, str) else text


def _join(values) -> str:
    return ",".join(f"{v:g}" for v in values)


def _values_type(name: str, hi: float):
    return Annotated[tuple[float, ...], BeforeValidator(_values(name, hi)), PlainSerializer(_join)]


class ExperimentConfig(CliModel):
    """The options of ``skynet experiment``."""

    loss: Annotated[_values_type("--loss-pct", 100.0), Cli(flag="--loss-pct", metavar="PCT[,PCT...]")] = Field(  # type: ignore[valid-type]
        default=(0.0, 5.0, 20.0, 40.0), description="random loss values, %%")
    delay: Annotated[_values_type("--delay-ms", 60_000.0), Cli(flag="--delay-ms", metavar="MS[,MS...]")] = Field(  # type: ignore[valid-type]
        default=(0.0, 50.0, 200.0), description="one-way delay values, ms")
    jitter: Annotated[_values_type("--jitter-ms", 60_000.0), Cli(flag="--jitter-ms", metavar="MS[,MS...]")] = Field(  # type: ignore[valid-type]
        default=(0.0,), description="jitter values, ms")
    recovery: Annotated[tuple[bool, ...], BeforeValidator(_recovery),
                        PlainSerializer(lambda v: ",".join("on" if x else "off" for x in v))] = Field(
        default=(True,), description="imagery recovery: on, off or on,off")
    repeat: int = Field(default=1, ge=1, le=1000, description="runs per cell")
    links: str = Field(default="all/udp", description="impaired links, in the launcher's --impair names (all/udp: "
                                                      "every best-effort link)")
    speed: float = Field(default=6.0, gt=0.0, lt=1000.0, description="simulation speed factor")
    uavs: Annotated[int, Cli(metavar="N")] = Field(default=3, ge=1, le=255, description="UAVs of each mission")
    scenario: str | None = Field(default=None, description="scenario file (default: the paper's monorail bridge)")
    method: Method = Field(default=default_of(DetectorConfig, "method"), description="the detector's method")
    vehicle: Vehicle = Field(default=default_of(EdgeConfig, "vehicle"), description=(
        "sim: the built-in vehicle; mavlink: sim autopilots over MAVLink (skynet mission --vehicle)"))
    flight: Flight = Field(default=default_of(EdgeConfig, "flight"), description=(
        "--vehicle mavlink: guided or auto (skynet mission --flight)"))
    seed: int = Field(default=0, ge=0, description="run k of every cell uses seed + k")
    out: str | None = Field(default=None, description="results folder (default reports/experiment-<time>)")
    timeout: Annotated[float, Cli(flag="--timeout-s", metavar="S")] = Field(default=300.0, gt=0.0, description="wall-clock limit of one run, s (then: hung)")
    insecure: bool = Field(default=False, description=(
        "fly the missions with --insecure: the best-effort class over plain UDP, where loss drops datagrams (the "
        "default secure mode carries it as a TLS stream through a TCP proxy: loss there is retransmission delay)"))
    dry_run: bool = Field(default=False, description="print the mission commands and stop")

    @model_validator(mode="after")
    def _links(self) -> ExperimentConfig:
        self.links = check_links(self.links, self.uavs)  # the launcher's own grammar, for this fleet
        if self.vehicle != "mavlink" and self.flight != default_of(EdgeConfig, "flight"):
            raise ValueError("--flight is the MAVLink autopilots' (with --vehicle mavlink)")
        return self
