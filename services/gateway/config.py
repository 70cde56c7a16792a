"""The gateway's typed configuration (``skynet gateway``): its options, their one default, their checks."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from protocol.bus import BusMode, BusOptions
from protocol.cliconfig import Cli

from .ingress import STATE_INGRESS_HZ


class GatewayConfig(BusOptions):
    """The options of the gateway router relay."""

    mode: BusMode = "router"
    id: str = Field(default="1", pattern=r"^[A-Za-z0-9_-]+$", description="gateway id (key space)")
    host: str = Field(default="127.0.0.1", description="listen host when --port is used")
    port: int | None = Field(default=None, ge=1, le=65534, description="TCP port; UDP uses port+1 (multilink)")
    period: Annotated[float, Cli(flag="--period-s", metavar="S")] = Field(default=1.0, gt=0.0, le=3600.0, description="statistics period, s")
    state_ingress_hz: Annotated[float, Cli(metavar="HZ")] = Field(
        default=STATE_INGRESS_HZ, ge=0.0,
        description="states a connected session may send per UAV key through the gateway, at most one per 1/HZ "
                    "(Zenoh ingress downsampling per face; services/gateway/ingress.py); 0: off")
    no_accept_guard: bool = Field(
        default=False, description="tls/ listeners without the accept guard (services/gateway/guard.py: it passes "
                                   "on only connections that start a TLS handshake, so connect-and-close or silent "
                                   "floods never reach zenoh)")

    @property
    def accept_guard(self) -> bool:
        """Whether tls/ listeners sit behind the accept guard (the default)."""
        return not self.no_accept_guard
