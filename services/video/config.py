"""The video service's typed configuration (``skynet video``)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from protocol.cliconfig import Cli
from services.attach import AttachOptions

#: the RTP payloads
VideoCodec = Literal["h264", "mjpeg"]


class VideoConfig(AttachOptions):
    """The options of the RTP video service."""

    codec: VideoCodec = Field(default="h264", description="h264: RFC 6184 (libx264 via PyAV); mjpeg: RFC 2435")
    host: Annotated[str, Cli(flag="--rtp-host", metavar="HOST")] = Field(
        default="127.0.0.1", description="where the RTP goes (IPv4; loopback by default)")
    port: Annotated[int, Cli(flag="--preview-port", metavar="PORT")] = Field(
        default=5600, ge=1, le=65535, description="UAV 1's preview port; UAV n's is PORT + 2(n-1)")
    capture: bool = Field(default=False, description="also stream the capture frames")
    capture_port: Annotated[int, Cli(metavar="PORT")] = Field(default=5700, ge=1, le=65535, description="UAV 1's capture port (with --capture)")
    uavs: Annotated[int, Cli(metavar="N")] = Field(default=0, ge=0, le=255, description="write the SDP files of UAVs 1..N at start")
    sdp_dir: Annotated[str, Cli(metavar="DIR")] = Field(default="sdp", description="folder of the SDP files")
