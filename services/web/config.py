"""The web page service's typed configuration (``skynet web``)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, field_validator

from protocol.cliconfig import Cli
from services.attach import AttachOptions

from .server import TOKEN_ENV, parse_listen


class WebConfig(AttachOptions):
    """The options of the live web page."""

    listen_web: Annotated[str, Cli(flag="--web", metavar="[HOST]:PORT")] = Field(
        default=":8080", description="[HOST]:PORT of the page (loopback by default)")
    rate: Annotated[float, Cli(flag="--rate-hz", metavar="HZ")] = Field(
        default=10.0, ge=1.0, le=30.0, description="snapshots per second on the WebSocket, Hz")
    scenario: str | None = Field(default=None, description="scenario file (default: the paper's monorail bridge)")
    token: str | None = Field(default=None, min_length=16, repr=False,
                              description=f"the page's access token (default: ${TOKEN_ENV}, else random per start; "
                                          "at least 16 characters)")
    allow_host: Annotated[list[str], Cli(metavar="NAME")] = Field(
        default=[], description="a host name the page also answers to besides its address and localhost "
                                "(repeatable)")
    frames: Annotated[str | None, Cli(metavar="DIR")] = Field(
        default=None, description="the detector's saved captures (a report's frames/): the defect count as the "
                                  "report counts it")

    @field_validator("listen_web")
    @classmethod
    def _listen(cls, v: str) -> str:
        parse_listen(v)
        return v
